"""Repeated evaluation (the robustness protocol): the same episodes K times, repeat r under
the protocol with ``repeat=r`` (so a seeded perturbation differs between repeats and is
the same whenever repeat r is run again), one ordinary run folder per repeat
(``RUN/repeat-00``, ...), and ``RUN/repeats.json`` naming them with their manifest hashes.
``scoring eval RUN`` reads such a folder as one robustness experiment; the folder's layout
(:data:`REPEATS_FILE`, :func:`repeat_folders`) is :mod:`catalog.store.repeat_sets`'s, which every
reader of one run uses to refuse a folder of repeats saying what to pass instead.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

from catalog.store.atomic import atomic_open
from catalog.store.manifest import Manifest, load_manifest
from catalog.store.repeat_sets import REPEATS_FILE, repeat_folders
from pipeline.jobs.spec import JobSpec, Storage
from pipeline.loop.conditions import MAX_REPEATS, EvalProtocol
from schemas.errors import AllEpisodesFailed, SpecError
from schemas.names import shorten

#: The folder layout's names stay importable from here (``pipeline migrate``, ``catalog info``).
if TYPE_CHECKING:
    from pipeline.jobs.evaluate import Report

__all__ = ["REPEATS_FILE", "evaluate_repeats", "run_repeats", "repeat_folder", "repeat_folders", "repeats_index"]


def repeat_folder(repeat: int) -> str:
    return f"repeat-{repeat:02d}"


def repeats_index(policy: str, slice_name: str, protocol: EvalProtocol, manifests: list[Manifest]) -> dict[str, Any]:
    """The ``repeats.json`` object: what was repeated and each repeat's run (path, hash)."""
    shared = protocol.to_dict()
    del shared["repeat"]
    return {
        "policy": policy,
        "slice": slice_name,
        "repeats": len(manifests),
        "protocol": shared,
        "runs": [{"path": repeat_folder(r), "hash": m.hash} for r, m in enumerate(manifests)],
    }


def evaluate_repeats(
    policy_ref: str, slice_name: str, out: str | Path, repeats: int, protocol: EvalProtocol, **options: Any
) -> list[Manifest]:
    """Run ``repeats`` evaluations into ``out/repeat-NN`` and index them (module docstring);
    the options are :func:`pipeline.jobs.evaluate.evaluate`'s. A folder holding a single
    run, or repeats of another experiment, is refused unless ``overwrite`` (then each repeat
    folder is replaced as ``evaluate`` replaces a run). With ``require_success``, when
    every episode of every repeat failed, AllEpisodesFailed (exit 3, as for one run) is
    raised after all of them and the index are written."""
    from pipeline.jobs.evaluate import DEFAULT_SHARD_SIZE, Report
    from pipeline.jobs.spec import job_spec

    if not isinstance(protocol, EvalProtocol):
        raise SpecError(f"protocol must be a pipeline.loop.conditions.EvalProtocol, got {shorten(repr(protocol))}")
    report = Report(**{k: options.pop(k) for k in ("summary", "stream", "require_success") if k in options})
    spec = job_spec(slice_name, out, {**options, "protocol": protocol}, shard_size=DEFAULT_SHARD_SIZE,
                    policy_ref=policy_ref)
    return run_repeats(spec, repeats, report)


def run_repeats(spec: JobSpec, repeats: int, report: Report) -> list[Manifest]:
    """:func:`evaluate_repeats` of an eval's :class:`~pipeline.jobs.spec.JobSpec`: repeat r
    runs its policy part's protocol with ``repeat=r`` into ``OUT/repeat-NN``."""
    from pipeline.jobs.evaluate import run_eval

    choice = spec.policy
    if choice is None:
        raise SpecError("repeats are of an eval: the JobSpec needs a policy")
    protocol, slice_name = choice.protocol, str(spec.selection.slice_name)
    if isinstance(repeats, bool) or not isinstance(repeats, int) or not 2 <= repeats <= MAX_REPEATS:
        raise SpecError(f"--repeats must be an integer in [2, {MAX_REPEATS}], got {shorten(repr(repeats))}")
    if spec.storage.remote:
        raise SpecError(f"--out {str(spec.storage.out)[:60]}: repeats are written to a local folder (upload it afterwards)")
    out, overwrite = spec.storage.folder, spec.storage.overwrite
    if (out / "catalog.json").exists():
        raise SpecError(f"{out} holds a single run: repeats need a folder of their own")
    index_path = out / REPEATS_FILE
    wanted = {"slice": slice_name, "repeats": repeats, "protocol": repeats_index("", slice_name, protocol, [])["protocol"]}
    if index_path.exists() and not overwrite:
        try:
            found = json.loads(index_path.read_text())
        except (OSError, ValueError) as exc:
            raise SpecError(f"{index_path}: unreadable ({exc}); --overwrite to replace the repeats") from None
        if not isinstance(found, dict) or any(found.get(k) != v for k, v in wanted.items()):
            raise SpecError(f"{out} holds repeats of another experiment: use another --out, or --overwrite")
    manifests = []
    name = choice.ref
    failed: list[AllEpisodesFailed] = []
    for r in range(repeats):
        repeat = dataclasses.replace(spec, storage=Storage(out / repeat_folder(r), overwrite),
                                     policy=dataclasses.replace(choice, protocol=dataclasses.replace(protocol, repeat=r)))
        try:
            manifest = run_eval(repeat, report)
        except AllEpisodesFailed as exc:  # written all the same: its manifest is read back below
            failed.append(exc)
            manifest = load_manifest(out / repeat_folder(r))
        name = str(manifest.extra.get("policy", choice.ref))
        manifests.append(manifest)
    out.mkdir(parents=True, exist_ok=True)
    with atomic_open(index_path, "w") as handle:
        handle.write(json.dumps(repeats_index(name, slice_name, protocol, manifests), indent=2, sort_keys=True) + "\n")
    if len(failed) == repeats:
        raise AllEpisodesFailed(f"in each of the {repeats} repeats {failed[0]}")
    return manifests
