"""Dyana in LeRobot's own evaluation: ``lerobot-eval --env.type=dyana
--env.discover_packages_path=pipeline.envhub`` (docs/guides/export-lerobot.md).

:mod:`pipeline.envhub.grasp` is the environment LeRobot steps (no lerobot import);
:mod:`pipeline.envhub.config` registers its ``EnvConfig`` as ``dyana`` (imports lerobot:
LeRobot's plugin loader imports it, with every module of this package);
:mod:`pipeline.envhub.env` is the EnvHub-style ``env.py`` with ``make_env``.
"""
