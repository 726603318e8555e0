"""A ``pipeline`` shim for the docs runner: an identical ``pipeline build`` is built once.

Builds are deterministic (same command, same bytes), so the runner puts this shim first on
PATH: ``pipeline build --slice S ...`` whose flags (all but ``--out``) match an earlier one
gets a copy of that build's ``OUT/S`` folder and its output, instead of building again
(``--quiet`` aside: it changes only the progress lines, and a cached build replays them
unless asked to be quiet).
Anything else (another command, ``--specs``, ``--scheduler``, an object-store ``--out``,
an existing ``OUT/S``) runs the real ``pipeline``. Two pages asking for the same build at
once (the xdist processes share the cache) build it once: the second waits on a lock.
The cache lives for one pytest session (``DYANA_DOCS_BUILD_CACHE``).
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

CACHE_ENV = "DYANA_DOCS_BUILD_CACHE"
REAL_ENV = "DYANA_DOCS_REAL_PIPELINE"
#: Flags whose build cannot be keyed by the command line alone.
UNCACHEABLE = ("--specs", "--scheduler", "--overwrite", "--help", "-h", "--version")


def cache_key(argv: list[str]) -> tuple[str, str, str] | None:
    """(key, slice, out) of a cacheable ``pipeline build`` command line, else None."""
    if not argv or argv[0] != "build" or any(a.split("=")[0] in UNCACHEABLE for a in argv):
        return None
    flags: dict[str, str] = {}
    rest = argv[1:]
    i = 0
    while i < len(rest):
        name, eq, value = rest[i].partition("=")
        if not name.startswith("--"):
            return None
        if not eq:
            if i + 1 < len(rest) and not rest[i + 1].startswith("--"):
                value, i = rest[i + 1], i + 1
            else:
                value = "true"
        flags[name] = value
        i += 1
    flags.pop("--quiet", None)  # progress lines only: the folder is the same
    out, slice_name = flags.pop("--out", "out"), flags.get("--slice")
    if slice_name is None or "://" in out:
        return None
    key = hashlib.sha256(json.dumps(sorted(flags.items())).encode()).hexdigest()[:16]
    return key, slice_name, out


def main(argv: list[str]) -> int:
    real = os.environ[REAL_ENV]
    found = cache_key(argv)
    cache = os.environ.get(CACHE_ENV)
    key, slice_name, out = found if found is not None else ("", "", "")
    target = Path(out) / slice_name
    if found is None or cache is None or target.exists():
        # Become the real command (same process id): `pipeline serve ... & kill $!` must reach it.
        os.execv(real, [real, *argv])
    # One build per command at a time: a page that asks while another builds it waits for the copy.
    with open(Path(cache) / f".{key}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        return _cached_build(real, argv, Path(cache) / key, target)


def _cached_build(real: str, argv: list[str], entry: Path, target: Path) -> int:
    """A copy of the cache ``entry`` into ``target``, or the real build, stored as ``entry``."""
    cache = entry.parent
    if entry.exists():
        shutil.copytree(entry / "folder", target)
        sys.stdout.write((entry / "stdout").read_text())
        if "--quiet" not in argv:
            sys.stderr.write((entry / "stderr").read_text())
        return 0
    result = subprocess.run([real, *argv], capture_output=True, text=True)
    sys.stdout.write(result.stdout)
    sys.stderr.write(result.stderr)
    if result.returncode == 0 and target.is_dir():
        staging = Path(tempfile.mkdtemp(dir=cache, prefix=".staging-"))
        shutil.copytree(target, staging / "folder")
        (staging / "stdout").write_text(result.stdout)
        (staging / "stderr").write_text(result.stderr)
        try:
            staging.rename(entry)
        except OSError:  # another page stored the same build first
            shutil.rmtree(staging)
    return result.returncode


def install(bin_dir: Path, cache: Path, real: str, root: Path) -> dict[str, str]:
    """Write the ``pipeline`` shim into ``bin_dir``; the environment variables it needs."""
    shim = bin_dir / "pipeline"
    shim.write_text(
        f"#!{sys.executable}\n"
        "import sys\n"
        f"sys.path.insert(0, {str(root)!r})\n"
        "from tests.docs.build_cache import main\n"
        "sys.exit(main(sys.argv[1:]))\n"
    )
    shim.chmod(0o755)
    return {CACHE_ENV: str(cache), REAL_ENV: real}
