"""Before a job keeps shards that another commit wrote: one of them rebuilt and compared.

The rule of :func:`pipeline.jobs.state.code_decision` keeps finished shards across a
commit that changes no byte (a docs-only ``git pull``), but a commit may also change the
bytes without bumping the dataset version (a bug, or a forgotten bump); kept shards would
then silently sit beside shards of other bytes. So when the recorded commit differs from
this checkout's (or either is unknown), one kept shard, the shortest (ties: the first),
is rebuilt in a scratch folder through the job's own shard task function (the same call a
worker makes, so builds, eval runs and object stores are checked alike) and each of its
files' sha256 is compared with the shard's record. A difference is refused in one line
naming the shard and the file. ``catalog verify --sample`` rebuilds from the stored specs
of a finished folder instead (:mod:`pipeline.jobs.verify`); this check needs no folder
files, only the records.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable, Sequence
from typing import Any

from catalog.store.records import ShardRecord
from pipeline.jobs.sink import ShardSink
from pipeline.jobs.tasks import ShardTask, TaskFn
from schemas.errors import ShardError


def sample_shard(records: Sequence[ShardRecord]) -> ShardRecord:
    """The shard a sample check rebuilds: the one of fewest episodes, then frames, then the first."""
    return min(records, key=lambda r: (r.end - r.first, r.frames, r.first))


def _short(commit: str | None) -> str:
    return "an unknown commit" if commit is None else f"commit {commit[:12]}"


def check_sample(
    records: Sequence[ShardRecord],
    tasks: Sequence[ShardTask],
    task_fn: TaskFn[Any],
    payload: Any,
    commits: tuple[str | None, str | None],
    where: str,
    say: Callable[[str], None] | None = None,
) -> None:
    """Rebuild :func:`sample_shard` of ``records`` with ``task_fn`` (its task from ``tasks``)
    and compare its files' sha256 with the record's; ``commits``: the recorded commit and
    this one. ShardError (one line naming ``where``, the shard and the file) on a difference;
    a note to ``say`` before the rebuild."""
    if not records:
        return
    record = sample_shard(records)
    task = next(t for t in tasks if (t.first, t.end) == (record.first, record.end))
    shown = f"{record.first}-{record.end - 1}"
    recorded, current = commits
    if say is not None:
        say(f"kept shards were written by {_short(recorded)}, this is {_short(current)}: "
            f"rebuilding shard {shown} to check that its bytes are the same")
    with tempfile.TemporaryDirectory(prefix="dyana-sample-") as scratch:
        rebuilt = ShardRecord.from_dict(task_fn(task, payload, ShardSink.folder(scratch))["record"])
    for kind, file in sorted(record.files.items()):
        other = rebuilt.files.get(kind)
        if other is None or other.sha256 != file.sha256:
            raise ShardError(
                f"{where}/{file.path}: shard {shown} rebuilt by {_short(current)} differs from what {_short(recorded)} "
                "wrote: the code changes bytes without a dataset-version bump; pass --overwrite to rebuild every shard"
            )
