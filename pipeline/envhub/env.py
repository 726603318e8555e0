"""The EnvHub-style ``env.py``: ``make_env`` as LeRobot's hub loader calls it.

LeRobot (``lerobot.envs.factory.make_env("user/repo", trust_remote_code=True)``) downloads a
repository's ``env.py``, imports it and calls ``make_env(n_envs=..., use_async_envs=...)``
(with ``cfg=`` when an ``EnvConfig`` asked): this file, uploaded to a Hub repository, or
loaded from a local folder (``importlib``; docs/guides/export-lerobot.md). Dyana must be
installed where it runs. Options come from ``cfg`` (a ``dyana`` EnvConfig's
``gym_kwargs``) and keyword arguments: :class:`pipeline.envhub.grasp.LeRobotGrasp`'s. Called
without either (the hub loader's plain call), it records nothing: ``record=FOLDER`` (with
``policy=PATH``) asks for a run.
"""

from __future__ import annotations

from typing import Any

from pipeline.envhub.grasp import make_vector_env

SUITE = "dyana"


def make_env(n_envs: int = 1, use_async_envs: bool = False, cfg: Any = None, **options: Any) -> dict[str, Any]:
    """``{"dyana": {0: vector env}}`` of ``n_envs`` environments (LeRobot's suites and tasks)."""
    kwargs = {"record": ""} | dict(getattr(cfg, "gym_kwargs", None) or {}) | options
    return {SUITE: {0: make_vector_env(n_envs, use_async_envs, **kwargs)}}
