"""Registering ``Dyana/Grasp-v0`` and ``Dyana/GraspFull-v0`` with Gymnasium, from a module
that imports nothing.

``Dyana/Grasp-v0`` is what RL libraries take as it comes: ``obs="both"`` (the image and
the hand's 148 state numbers, fixed shapes) and ``normalize_actions=True`` (the Box
[-1, 1]^18), so Stable-Baselines3's ``MultiInputPolicy`` and ``AsyncVectorEnv``'s shared
memory need no options. ``Dyana/GraspFull-v0`` is the full observation dict and the real
actions, the policy contract ``pipeline eval`` uses (``DyanaEnv()``'s own defaults).

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
#: The full observation dict and the dataset's absolute actions.
FULL_ENV_ID = "Dyana/GraspFull-v0"
#: The registered environment's episodes source: a ``reset(seed=s)`` runs episode
#: ``s % 1000`` of this slice (``DyanaEnv(episodes=...)``).
DEFAULT_EPISODES = "test-1k"
#: Each registered id's keyword arguments (``gymnasium.make`` overrides any of them).
DEFAULTS = {
    ENV_ID: {"episodes": DEFAULT_EPISODES, "obs": "both", "normalize_actions": True},
    FULL_ENV_ID: {"episodes": DEFAULT_EPISODES, "obs": "full", "normalize_actions": False},
}


def register() -> bool:
    """Register :data:`ENV_ID` and :data:`FULL_ENV_ID` with Gymnasium (idempotent); returns True.

    Also what ``gymnasium.make("pipeline.loop.env:Dyana/Grasp-v0")`` relies on in a fresh
    interpreter (Gymnasium imports the module named before the colon, which calls this),
    and the ``gymnasium.envs`` entry point (named ``Dyana``, the namespace). The passive
    env checker stays on: observations match their spaces exactly.
    """
    # from the submodule: a plugin runs while ``gymnasium`` itself is still importing
    from gymnasium.envs.registration import register as register_env
    from gymnasium.envs.registration import registry

    for env_id, kwargs in DEFAULTS.items():
        if env_id not in registry:
            register_env(id=env_id, entry_point="pipeline.loop.env:DyanaEnv", kwargs=dict(kwargs))
    return True
