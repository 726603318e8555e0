"""Episodes run outside `pipeline eval`, kept until their run is written.

LeRobot's own evaluation loop (``lerobot-eval --env.type=dyana``, :mod:`pipeline.envhub`)
steps Dyana's recorded environment itself: each episode it finishes is staged here, one
file per episode index (its :class:`~pipeline.loop.rollout.RolloutResult`), and the run
is then written by `pipeline eval`'s own job (:func:`pipeline.jobs.evaluate.run_eval` with
a :class:`Recorded`), which takes each episode's result from the staging folder instead of
running a policy: the same shards, statistics and ``catalog.json``.

:func:`staged_episode` and :func:`held_result` are the same result as `pipeline eval`'s own
shard tasks stage it while their shard is in flight (:mod:`catalog.tables.partial`).
"""

from __future__ import annotations

import os
import pickle
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from catalog.tables.partial import StagedEpisode
from pipeline.loop.rollout import RolloutResult
from schemas.errors import DyanaError, SpecError
from schemas.names import shorten
from schemas.spec import EpisodeSpec

SUFFIX = ".episode"


@dataclass(frozen=True)
class Recorded:
    """Episodes already run: the policy's ``name`` and ``privileged`` flag as the run
    records them, and the ``folder`` their results are staged in (:func:`stage_result`)."""

    name: str
    privileged: bool
    folder: str

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise SpecError(f"Recorded: name must be a non-empty str, got {shorten(repr(self.name))}")
        if not isinstance(self.privileged, bool):
            raise SpecError(f"Recorded: privileged must be True or False, got {shorten(repr(self.privileged))}")
        if not isinstance(self.folder, str) or not os.path.isdir(self.folder):
            raise SpecError(f"Recorded: folder must be an existing folder, got {shorten(repr(self.folder))}")


def _path(folder: str | Path, index: int) -> Path:
    return Path(folder) / f"{index}{SUFFIX}"


def stage_result(folder: str | Path, result: RolloutResult) -> None:
    """Keep ``result`` in ``folder`` under its episode index (written whole, then renamed)."""
    path = _path(folder, result.spec.episode_index)
    partial = path.with_name(path.name + ".partial")
    partial.write_bytes(pickle.dumps(result, protocol=pickle.HIGHEST_PROTOCOL))
    os.replace(partial, path)


def staged_indices(folder: str | Path) -> list[int]:
    """The episode indices staged in ``folder``, in order."""
    return sorted(int(p.name[: -len(SUFFIX)]) for p in Path(folder).glob(f"*{SUFFIX}") if p.name[: -len(SUFFIX)].isdigit())


def staged_result(folder: str | Path, spec: EpisodeSpec) -> RolloutResult:
    """The staged result of ``spec``'s episode; DyanaError when none is staged or it ran another spec."""
    path = _path(folder, spec.episode_index)
    try:
        result = pickle.loads(path.read_bytes())
    except OSError:
        raise DyanaError(f"{shorten(str(path))}: episode {spec.episode_index} was not recorded") from None
    if not isinstance(result, RolloutResult) or result.spec.spec_hash != spec.spec_hash:
        raise DyanaError(f"{shorten(str(path))}: the recorded episode is not {spec.episode_id} of the run")
    return result


def staged_episode(result: RolloutResult, audit: list[dict[str, Any]]) -> StagedEpisode:
    """A rolled-out episode as its shard stages it: what the writer records, the counts the
    task's statistics add and the episode's audit records."""
    info = {"status": result.status, "error": result.error, "steps": result.steps, "calls": result.calls,
            "localized": result.localized, "grasped": result.grasped, "policy_s": result.policy_s, "audit": audit}
    return StagedEpisode(result.spec, result.frames, result.images, info)


def held_result(held: StagedEpisode | None) -> tuple[RolloutResult, list[dict[str, Any]]] | None:
    """A staged episode (:func:`staged_episode`) as its rollout's result and audit records;
    None for none, or for one whose counts are not what :func:`staged_episode` keeps."""
    if held is None:
        return None
    info = held.info
    try:
        result = RolloutResult(held.spec, held.frames, held.images, str(info["status"]), str(info["error"]),
                               int(info["steps"]), int(info["calls"]), bool(info["localized"]),
                               bool(info["grasped"]), float(info["policy_s"]))
        records = [dict(record) for record in info["audit"]]
    except (KeyError, TypeError, ValueError):
        return None
    return result, records
