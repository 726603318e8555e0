"""The versions that determine a written file's bytes, as ``catalog.json`` records them.

Dyana pins every option that affects the bytes of a shard, but not the libraries behind
those options: pyarrow writes its own version into each Parquet footer and bundles the
zstd that compresses the columns, OpenCV bundles the libjpeg-turbo that encodes the
frames, pybullet's TinyRenderer draws them, numpy and scipy compute the states, mcap and
the protobuf packages lay out the MCAP file, and simplejpeg decodes the images a policy
sees. A manifest's ``versions`` maps Python and each of these distributions to the
version that wrote the folder (``.ci/constraints.txt`` pins them for an install).

:func:`version_differences` compares a record with this installation: ``catalog info``
says from it whether a rebuild is expected to be byte for byte, and ``catalog verify`` /
``pipeline replay`` name the differing versions when rebuilt bytes differ.
"""

from __future__ import annotations

import platform
from collections.abc import Mapping
from functools import cache
from importlib import metadata
from types import MappingProxyType

from schemas.errors import ShardError
from schemas.names import printable

#: The manifest key.
VERSIONS_KEY = "versions"
#: The distributions whose versions a manifest records, besides ``python``.
BYTE_DISTRIBUTIONS = (
    "numpy",
    "scipy",
    "pybullet",
    "opencv-python-headless",
    "simplejpeg",
    "pyarrow",
    "mcap",
    "mcap-protobuf-support",
    "protobuf",
    "foxglove-schemas-protobuf",
)


def installed_versions() -> dict[str, str | None]:
    """This installation's ``python`` version and each :data:`BYTE_DISTRIBUTIONS`' version
    (``None`` for one not installed); read once per process (a job asks several times, and
    each read scans the installed distributions' metadata: 70 ms)."""
    return dict(_installed())


@cache
def _installed() -> tuple[tuple[str, str | None], ...]:
    found: dict[str, str | None] = {"python": platform.python_version()}
    for name in BYTE_DISTRIBUTIONS:
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            found[name] = None
    return tuple(found.items())


def checked_versions(value: object) -> Mapping[str, str | None]:
    """A manifest's ``versions`` value, checked: an object of names to version strings (or
    null); ShardError naming the value otherwise."""
    if not isinstance(value, Mapping) or not value:
        raise ShardError(f"{VERSIONS_KEY} must be a non-empty object of names to versions, got {printable(value, 80)}")
    for name, version in value.items():
        if not isinstance(name, str) or not name or not (version is None or (isinstance(version, str) and version)):
            raise ShardError(f"{VERSIONS_KEY}[{printable(name, 40)}] must be a version string or null, "
                             f"got {printable(version, 40)}")
    return MappingProxyType(dict(value))


def version_differences(recorded: Mapping[str, str | None], installed: Mapping[str, str | None]) -> list[str]:
    """``recorded NAME A, installed B`` for each recorded name whose installed version differs,
    in the record's sorted order; empty when they all match."""
    return [
        f"recorded {name} {_shown(version)}, installed {_shown(installed.get(name))}"
        for name, version in sorted(recorded.items())
        if installed.get(name) != version
    ]


def _shown(version: str | None) -> str:
    return "(none)" if version is None else version


def mismatch_note(recorded: Mapping[str, str | None] | None, installed: Mapping[str, str | None] | None = None) -> str:
    """What to append to a "rebuilt bytes differ" message: ``; recorded pyarrow 21.0.0,
    installed 22.0.0`` for each version that differs, nothing when they all match, and a
    word when the folder records none (written before Dyana recorded them)."""
    if recorded is None:
        return "; the folder records no library versions (written before Dyana recorded them)"
    differ = version_differences(recorded, installed_versions() if installed is None else installed)
    return "".join(f"; {d}" for d in differ)
