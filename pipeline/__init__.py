"""Composition and execution, grouped by job:

- :mod:`pipeline.stages`: the episode stage chain (spec -> states and actions -> frames);
- :mod:`pipeline.loop`: the closed loop (the environment, its recorder and protocol
  wrappers, checker, rollout with deadlines);
- :mod:`pipeline.policies`: the built-in policies and the policy protocol (``Policy``,
  ``Observation``, ``Task``);
- :mod:`pipeline.remote`: policies over the network (protocol, server, client);
- :mod:`pipeline.policy_registry`: every kind of ``--policy`` reference, one registration each;
- :mod:`pipeline.jobs`: sharded jobs and their folders (runner, build, eval, replay, verify, view);
- :mod:`pipeline.cli`, :mod:`pipeline.cli_catalog`: the ``pipeline`` and ``catalog`` commands.

Importing the package stays light: :func:`episode` loads the stage on first call.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from schemas.frames import EpisodeFrames
    from schemas.spec import EpisodeSpec


def episode(spec: EpisodeSpec) -> EpisodeFrames:
    """Ground-truth states and actions of every frame of ``spec`` (float32 arrays, no
    rendering): :func:`pipeline.stages.episode.episode`.

    Raises :class:`schemas.errors.InfeasibleError` when the interception cannot be planned,
    and :class:`schemas.errors.SpecError` naming the argument when ``spec`` is not an EpisodeSpec.
    """
    from pipeline.stages.episode import episode as run

    return run(spec)


__all__ = ["episode"]
