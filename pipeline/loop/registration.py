"""Registering ``Dyana/Grasp-v0`` with Gymnasium, from a module that imports nothing.

This module is the ``gymnasium.envs`` entry point in pyproject.toml. Gymnasium 0.26-0.29
call every such entry point at the end of ``import gymnasium``: if Dyana's own import of
Gymnasium triggers that (``import pipeline.loop.env`` first), the entry point runs while
:mod:`pipeline.loop.env` is still half imported, so it must not be that module, nor import
it. Here the environment is named by a string (``"pipeline.loop.env:DyanaEnv"``, imported
by ``gymnasium.make``) and its episodes by a slice name, so registering imports nothing
from Dyana; :mod:`pipeline.loop.env` calls :func:`register` on import as well (Gymnasium
1.x loads no plugins).
"""

from __future__ import annotations

ENV_ID = "Dyana/Grasp-v0"
#: The registered environment's episodes source: a ``reset(seed=s)`` runs episode
#: ``s % 1000`` of this slice (``DyanaEnv(episodes=...)``).
DEFAULT_EPISODES = "test-1k"


def register() -> bool:
    """Register :data:`ENV_ID` with Gymnasium (idempotent); returns True.

    Also what ``gymnasium.make("pipeline.loop.env:Dyana/Grasp-v0")`` relies on in a fresh
    interpreter (Gymnasium imports the module named before the colon, which calls this),
    and the ``gymnasium.envs`` entry point (named ``Dyana``, the namespace). The passive
    env checker stays on: observations match their spaces exactly.
    """
    # from the submodule: a plugin runs while ``gymnasium`` itself is still importing
    from gymnasium.envs.registration import register as register_env
    from gymnasium.envs.registration import registry

    if ENV_ID not in registry:
        register_env(id=ENV_ID, entry_point="pipeline.loop.env:DyanaEnv", kwargs={"episodes": DEFAULT_EPISODES})
    return True
