"""Repeated evaluation (the robustness protocol): the same episodes K times, repeat r under
the protocol with ``repeat=r`` (so a seeded perturbation differs between repeats and is
the same whenever repeat r is run again), one ordinary run folder per repeat
(``RUN/repeat-00``, ...), and ``RUN/repeats.json`` naming them with their manifest hashes.
``scoring eval RUN`` reads such a folder as one robustness experiment; the folder's layout
(:data:`REPEATS_FILE`, :func:`repeat_folders`) is :mod:`catalog.repeat_sets`'s, which every
reader of one run uses to refuse a folder of repeats saying what to pass instead.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

from catalog.atomic import atomic_open
from catalog.manifest import Manifest, load_manifest
from catalog.repeat_sets import REPEATS_FILE, repeat_folders
from catalog.storage import is_url
from pipeline.loop.conditions import MAX_REPEATS, EvalProtocol
from schemas.errors import AllEpisodesFailed, SpecError
from schemas.names import shorten

#: The folder layout's names stay importable from here (``pipeline migrate``, ``catalog info``).
__all__ = ["REPEATS_FILE", "evaluate_repeats", "repeat_folder", "repeat_folders", "repeats_index"]


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
    """Run ``repeats`` evaluations into ``out/repeat-NN`` and index them (module docstring).
    A folder holding a single run, or repeats of another experiment, is refused unless
    ``overwrite`` (then each repeat folder is replaced as ``evaluate`` replaces a run).
    With ``require_success``, when every episode of every repeat failed, AllEpisodesFailed
    (exit 3, as for one run) is raised after all of them and the index are written."""
    from pipeline.jobs.evaluate import evaluate

    if not isinstance(protocol, EvalProtocol):
        raise SpecError(f"protocol must be a pipeline.loop.conditions.EvalProtocol, got {shorten(repr(protocol))}")
    if isinstance(repeats, bool) or not isinstance(repeats, int) or not 2 <= repeats <= MAX_REPEATS:
        raise SpecError(f"--repeats must be an integer in [2, {MAX_REPEATS}], got {shorten(repr(repeats))}")
    if is_url(out):
        raise SpecError(f"--out {str(out)[:60]}: repeats are written to a local folder (upload it afterwards)")
    out = Path(out)
    if (out / "catalog.json").exists():
        raise SpecError(f"{out} holds a single run: repeats need a folder of their own")
    index_path = out / REPEATS_FILE
    wanted = {"slice": slice_name, "repeats": repeats, "protocol": repeats_index("", slice_name, protocol, [])["protocol"]}
    if index_path.exists() and not options.get("overwrite", False):
        try:
            found = json.loads(index_path.read_text())
        except (OSError, ValueError) as exc:
            raise SpecError(f"{index_path}: unreadable ({exc}); --overwrite to replace the repeats") from None
        if not isinstance(found, dict) or any(found.get(k) != v for k, v in wanted.items()):
            raise SpecError(f"{out} holds repeats of another experiment: use another --out, or --overwrite")
    manifests = []
    name = policy_ref
    failed: list[AllEpisodesFailed] = []
    for r in range(repeats):
        try:
            manifest = evaluate(policy_ref, slice_name, out / repeat_folder(r),
                                protocol=dataclasses.replace(protocol, repeat=r), **options)
        except AllEpisodesFailed as exc:  # written all the same: its manifest is read back below
            failed.append(exc)
            manifest = load_manifest(out / repeat_folder(r))
        name = str(manifest.extra.get("policy", policy_ref))
        manifests.append(manifest)
    out.mkdir(parents=True, exist_ok=True)
    with atomic_open(index_path, "w") as handle:
        handle.write(json.dumps(repeats_index(name, slice_name, protocol, manifests), indent=2, sort_keys=True) + "\n")
    if len(failed) == repeats:
        raise AllEpisodesFailed(f"in each of the {repeats} repeats {failed[0]}")
    return manifests
