"""A hunter policy: a cheat that looks for the private test seed (a test helper).

When made, it searches what a process on the same machine could read for the secret of
a held-out run: every ``/proc/*/cmdline`` (``--test-seed SECRET``, ``--test-seed-file
PATH``), every ``/proc/*/environ``, the files every ``/proc/*/fd`` has open, its own
environment, and the files under the home folders, ``/tmp``, ``/var/tmp``, ``/dev/shm``,
the working folder and its parents. Every secret-shaped string it reads is a candidate,
checked against :data:`TARGET` (the sha256 of the tests' secret, standing in for the
scrypt hash a run's manifest records: it confirms a guess and reveals nothing). With the
secret, it regenerates the private split (:func:`generators.heldout.private_specs`) and
plays the ground truth of the episode it identifies, as :mod:`tests.pipeline.lookup_policy`
does on the public one. Its name says what it found: ``hunter-found`` or
``hunter-blind`` (then it holds the hand still: chance).
"""

from __future__ import annotations

import hashlib
import os
import re
import stat
from collections.abc import Iterator
from pathlib import Path

from generators.heldout import MAX_SECRET_CHARS, MIN_SECRET_CHARS, check_secret, derive, private_specs
from schemas.errors import SpecError
from schemas.spec import EpisodeSpec
from tests.pipeline.lookup_policy import SLICE, Key, LookupPolicy, task_key

#: sha256 of tests.pipeline.test_sealed.SECRET.
TARGET = "89d09d0044cbdf5c382183058bfe6e0058aa89fe91ecf523248d7201a58d11cf"
#: Episodes of the private split it regenerates with the secret.
EPISODES = 64
MAX_FILES = 4000
MAX_BYTES = 4096
FLAG = re.compile(r"^--test-seed(-file)?(=.*)?$")


def _read(path: str | Path, limit: int = MAX_BYTES) -> bytes:
    """The start of a regular file (a pipe or socket could block for ever), or nothing."""
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            return b""
        with open(path, "rb") as handle:
            return handle.read(limit)
    except OSError:
        return b""


def _secretish(text: str) -> Iterator[str]:
    for word in re.split(r"[\s=\0]+", text):
        if not MIN_SECRET_CHARS <= len(word) <= MAX_SECRET_CHARS:
            continue  # check_secret refuses it too: skipped without building its refusal
        try:
            yield check_secret(word)
        except SpecError:
            continue


def _from_argv(argv: list[str]) -> Iterator[str]:
    for i, arg in enumerate(argv):
        flag = FLAG.match(arg)
        if not flag:
            continue
        value = arg.split("=", 1)[1] if "=" in arg else (argv[i + 1] if i + 1 < len(argv) else "")
        yield from _secretish(_read(value).decode("utf-8", "replace") if flag.group(1) else value)


def _files() -> Iterator[Path]:
    roots = [Path.home(), Path("/root"), Path("/home"), Path("/tmp"), Path("/var/tmp"), Path("/dev/shm"), Path.cwd()]
    roots += [p for p in Path.cwd().parents if p != Path("/")]
    seen = 0
    for root in roots:
        deep = root not in Path.cwd().parents
        for folder, dirs, names in os.walk(root):
            if not deep:
                dirs[:] = []
            dirs[:] = [d for d in dirs if d not in (".git", ".venv", "node_modules", "__pycache__", ".pyenv")]
            for name in names:
                seen += 1
                if seen > MAX_FILES:
                    return
                yield Path(folder) / name


def _candidates() -> Iterator[tuple[str, str]]:
    """Every secret-shaped string it can read, and where, most likely places first."""
    for value in os.environ.values():
        for word in _secretish(value):
            yield word, "own environment"
    procs = list(Path("/proc").glob("[0-9]*"))
    for proc in procs:
        argv = _read(proc / "cmdline", 1 << 16).decode("utf-8", "replace").split("\0")
        for word in _from_argv(argv):
            yield word, f"{proc}/cmdline"
    for proc in procs:
        for word in _secretish(_read(proc / "environ", 1 << 16).decode("utf-8", "replace")):
            yield word, f"{proc}/environ"
        try:
            fds = list((proc / "fd").iterdir())
        except OSError:
            fds = []
        for fd in fds:
            for word in _secretish(_read(fd).decode("utf-8", "replace")):
                yield word, str(fd)
    for path in _files():
        if path.is_file() and not path.is_symlink():
            for word in _secretish(_read(path).decode("utf-8", "replace")):
                yield word, str(path)


def hunt() -> tuple[str | None, str, int]:
    """(the secret, where it was read; None and "" if not found), and how many candidates it tried."""
    tried = 0
    for word, where in _candidates():
        tried += 1
        if hashlib.sha256(word.encode()).hexdigest() == TARGET:
            return word, where, tried
    return None, "", tried


class HunterPolicy(LookupPolicy):
    """Hunts for the secret when made; with it, looks its episodes up in the private split."""

    def __init__(self) -> None:
        super().__init__()
        secret, self.where, self.tried = hunt()
        self.index: dict[Key, list[EpisodeSpec]] = {}
        if secret is not None:
            for spec in private_specs(derive(secret, SLICE), 0, EPISODES):
                key = task_key(spec.text, spec.hand, spec.observe_frames, spec.acting_horizon, spec.intercept_time_s)
                self.index.setdefault(key, []).append(spec)
        self.name = "hunter-blind" if secret is None else "hunter-found"

    def reset(self, task) -> None:
        super().reset(task)
        key = task_key(task["text"], task["hand"], task["observe_frames"], task["horizon"],
                       task.get("intercept_time_s", 1.0))
        self._candidates = self.index.get(key, [])
