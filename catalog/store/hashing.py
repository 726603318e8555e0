"""Content hashes: sha256 of files and the slice hash of a manifest.

Canonical JSON (:func:`canonical_json`) is ``json.dumps`` with sorted keys, the
separators ``","`` and ``":"`` (no spaces), ASCII only (non-ASCII escaped as
``\\uXXXX``) and NaN/Infinity refused, encoded as UTF-8.

The slice hash (:func:`slice_hash`) is the hex sha256 of the canonical JSON of::

    {"files": [<hex sha256>, ...], "seed": <int or null>, "settings": <settings object>,
     "slice": <name>, "stats": <hex sha256 of stats.json or null>}

where ``files`` lists the sha256 of every file of every shard: shards in manifest
order (increasing first episode), and within a shard the kinds in the order
``frames``, ``episodes``, ``mcap`` (:data:`FILE_KINDS`; ``mcap`` only when built). So everything a reader relies
on (the shards, the normalisation statistics, the settings with the dataset version,
the slice name and seed) is covered. Paths, sizes and episode ranges are not hashed:
they are implied by the files and the settings.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from collections.abc import Iterable, Mapping
from typing import Any

from catalog.store.storage import open_binary

#: The files of a shard, in hashing order.
FILE_KINDS = ("frames", "episodes", "mcap")

_SHA256 = re.compile(r"^[0-9a-f]{64}$")
_BLOCK = 1 << 20


def canonical_json(value: Any) -> str:
    """The canonical JSON text of ``value`` (see the module docstring)."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)


def is_sha256(value: Any) -> bool:
    """True for a 64-character lower-case hex digest."""
    return isinstance(value, str) and bool(_SHA256.match(value))


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: str | os.PathLike[str]) -> str:
    """Hex sha256 of a file, read in 1 MiB blocks."""
    digest = hashlib.sha256()
    with open_binary(path) as handle:
        while block := handle.read(_BLOCK):
            digest.update(block)
    return digest.hexdigest()


def slice_hash(
    settings: Mapping[str, Any],
    file_hashes: Iterable[str],
    *,
    slice_name: str | None = None,
    seed: int | None = None,
    stats: str | None = None,
) -> str:
    """The slice hash over ``settings``, the ordered ``file_hashes``, the slice name,
    the seed and the statistics file's sha256."""
    hashes = list(file_hashes)
    for value in [*hashes, *([stats] if stats is not None else [])]:
        if not is_sha256(value):
            raise ValueError(f"not a sha256 hex digest: {value!r}")
    payload = {"files": hashes, "seed": seed, "settings": dict(settings), "slice": slice_name, "stats": stats}
    return sha256_bytes(canonical_json(payload).encode("utf-8"))
