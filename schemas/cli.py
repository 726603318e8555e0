"""One command-line layer for the three console scripts (`pipeline`, `catalog`, `scoring`).

A program is a list of :class:`Command` (name, help, arguments, handler) given to
:func:`run`. Shared options are defined once here (:func:`add_episodes`,
:func:`add_workers`, ...), so a flag means and checks the same in every command. The
layer guarantees what users and scripts rely on:

- usage errors and every expected failure are one line, ``PROG CMD: error: MESSAGE``
  on stderr, with bad values echoed truncated; never a traceback;
- exit codes come from one map (:data:`EXIT_CODES`): 2 for bad input, an unusable
  file or an unusable object store (its client's errors are recognised by module,
  :mod:`schemas.storage_faults`, without importing it), 1 for a replay that differs, 3 for an eval whose every episode failed (its run
  written), 130 on Ctrl-C, 141 when the reader of stdout went away
  (``catalog specs ... | head``), 0 otherwise;
- a full or closed stdout is reported once, cleanly, even when only the final flush
  finds it;
- ``--version`` on the program and on every command: the code version and the dataset
  version it writes (:data:`VERSION`);
- progress lines (:class:`ProgressMeter`) go to stderr, at most one per
  :data:`PROGRESS_INTERVAL_S` plus the last, and ``--quiet`` turns them off.

It lives in ``schemas`` (which imports nothing of ours but itself) so that ``scoring``,
which must not import ``pipeline``, shares it.
"""

from __future__ import annotations

import argparse
import errno
import os
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from schemas.errors import AllEpisodesFailed, DyanaError, ReplayMismatch, SpecError
from schemas.names import printable, redact_credentials, shorten
from schemas.regular_files import file_kind, open_regular
from schemas.renderers import DEFAULT_RENDERER, RENDERER_VERSIONS, RENDERERS, SPLAYED_HAND_COMMIT
from schemas.storage_faults import describe_storage_fault, is_storage_fault
from schemas.versions import CODE_VERSION, DATASET_VERSION

#: What ``--version`` says after the program's name: a folder's ``catalog info`` names the same two.
VERSION = f"dyana {CODE_VERSION}, writes dataset {DATASET_VERSION}"
#: The longest error line printed (values inside it are cut shorter, see schemas.names).
MESSAGE_LIMIT = 600
EXIT_OK, EXIT_DIFFERENT, EXIT_BAD_INPUT, EXIT_INTERRUPTED, EXIT_BROKEN_PIPE = 0, 1, 2, 130, 141
#: An eval that wrote its run but every episode failed (a policy or transport error).
EXIT_ALL_FAILED = 3
#: Exception type -> exit code, most specific first.
EXIT_CODES: tuple[tuple[type[BaseException], int], ...] = (
    (ReplayMismatch, EXIT_DIFFERENT),
    (AllEpisodesFailed, EXIT_ALL_FAILED),
    (DyanaError, EXIT_BAD_INPUT),
    (OSError, EXIT_BAD_INPUT),
)


class OneLineParser(argparse.ArgumentParser):
    """argparse whose usage errors are one line and exit 2, like every other Dyana error."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {shorten(message, MESSAGE_LIMIT)} (see --help)\n")


@dataclass(frozen=True)
class Command:
    """One subcommand: ``add_arguments(parser)`` declares its flags, ``run(args)`` returns the exit code."""

    name: str
    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]


# --- argument types --------------------------------------------------------------


def positive_int(text: str) -> int:
    """A whole number >= 1, with a message naming the bad value."""
    return _number(text, int, "a whole number", lambda v: v >= 1, "a number >= 1")


def _number(text: str, convert: Callable[[str], Any], what: str, valid: Callable[[Any], bool], wanted: str) -> Any:
    try:
        value = convert(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {shorten(text)!r}") from None
    if not valid(value):
        raise argparse.ArgumentTypeError(f"expected {wanted}, got {shorten(text)!r}")
    return value


def positive_float(text: str) -> float:
    """A finite number > 0."""
    return _number(text, float, "a number", lambda v: 0 < v < float("inf"), "a number > 0")


def output_path(text: str) -> str:
    """A file or folder name to write: one the file system layer can encode (a name that is not
    valid UTF-8 reaches Python as surrogates, which pyarrow and others cannot write)."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        raise argparse.ArgumentTypeError(f"expected a name in UTF-8, got '{printable(text)}'") from None
    return text


def port(text: str) -> int:
    """A TCP port, 0 meaning any free one."""
    return _number(text, int, "a port number", lambda v: 0 <= v <= 65535, "a port in [0, 65535] (0 = any free port)")


# --- shared options ----------------------------------------------------------------


def add_episodes(parser: argparse.ArgumentParser, what: str = "only the first N episodes") -> None:
    parser.add_argument("--episodes", type=positive_int, metavar="N", help=what)


def default_worker_count() -> int:
    """One worker per core this process may use."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


#: True while the documentation site renders the parsers (``docs/hooks/cli_reference.py``):
#: help texts then leave out what depends on the machine building the site (its cores).
FOR_THE_SITE = False


def cores_here() -> str:
    """``", N here"``: this machine's default worker count, for a help text; empty on the site."""
    return "" if FOR_THE_SITE else f", {default_worker_count()} here"


def add_workers(parser: argparse.ArgumentParser) -> None:
    """``--workers`` and ``--scheduler``: where the shards run."""
    parser.add_argument(
        "--workers", type=positive_int, default=None,
        help=f"local single-threaded worker processes (default: one per core{cores_here()}; a job of one shard "
        "runs in this process)",
    )
    parser.add_argument("--scheduler", help="address of an existing Dask scheduler, e.g. tcp://127.0.0.1:8786")


def add_resolution(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--resolution", type=positive_int, default=224, help="image side in pixels (default: 224)")


def add_renderer(parser: argparse.ArgumentParser) -> None:
    """``--renderer``: how frames are drawn, which decides the dataset version (:mod:`schemas.renderers`)."""
    parser.add_argument(
        "--renderer", choices=RENDERERS, default=DEFAULT_RENDERER,
        help=f"window: draw only the window around the hand and object (default; dataset "
        f"{RENDERER_VERSIONS['window']}); full: refused (dataset 3.0.0's hand is gone: commit "
        f"{SPLAYED_HAND_COMMIT} builds it)",
    )


def add_shard_size(parser: argparse.ArgumentParser, default: int) -> None:
    parser.add_argument(
        "--shard-size", type=positive_int, default=default, help=f"episodes per shard (default: {default})"
    )


def add_formats(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--formats", default="parquet,mcap", metavar="LIST",
        help="what to store: parquet,mcap (default) or parquet (MCAP is for viewing in Foxglove; "
        "every reader uses the Parquet tables)",
    )


def add_overwrite(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--overwrite", action="store_true",
        help="replace what the output folder holds if it is another build or run (nothing is replaced without it)",
    )


def add_quiet(parser: argparse.ArgumentParser, what: str = "no progress lines") -> None:
    parser.add_argument("--quiet", action="store_true", help=what)


def add_test_seed(parser: argparse.ArgumentParser, what: str) -> None:
    """``--test-seed SECRET`` / ``--test-seed-file FILE`` (read with :func:`read_test_seed`)."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--test-seed", metavar="SECRET", help=f"{what} (>= 16 characters; "
                       "make one with: python -c \"import secrets; print(secrets.token_hex(16))\")")
    group.add_argument("--test-seed-file", metavar="FILE",
                       help="the same secret read from FILE's first line (keeps it out of the shell's history; "
                       "- reads it from stdin)")


#: The most bytes a --test-seed-file is read for (a secret is one short line).
TEST_SEED_FILE_BYTES = 4096


def _read_seed_file(path: str) -> bytes:
    """At most :data:`TEST_SEED_FILE_BYTES` + 1 bytes of the regular file ``path``."""
    try:
        handle, status = open_regular(path)  # a FIFO with no writer would block for ever
        if handle is None:
            raise SpecError(f"--test-seed-file {shorten(path, 80)}: {file_kind(status.st_mode)}, not a regular file")
        with handle:
            return handle.read(TEST_SEED_FILE_BYTES + 1)
    except OSError as exc:
        raise SpecError(f"--test-seed-file {shorten(path, 80)}: cannot read it ({exc.strerror or exc})") from None


def read_test_seed(args: argparse.Namespace) -> str | None:
    """The secret of ``--test-seed`` or ``--test-seed-file`` (its first line; ``-``: stdin),
    or None; an unreadable file is a SpecError naming it (never the secret)."""
    if getattr(args, "test_seed_file", None) is None:
        return getattr(args, "test_seed", None)
    path = args.test_seed_file
    if path == "-":  # a pipe: no command line names where the secret is
        data, path = sys.stdin.buffer.read(TEST_SEED_FILE_BYTES + 1), "- (stdin)"
    else:
        data = _read_seed_file(path)
    if len(data) > TEST_SEED_FILE_BYTES:
        raise SpecError(f"--test-seed-file {shorten(path, 80)}: longer than {TEST_SEED_FILE_BYTES} bytes, not a secret")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise SpecError(f"--test-seed-file {shorten(path, 80)}: not UTF-8 text") from None
    lines = text.splitlines()
    return lines[0] if lines else ""


#: The shortest time between two progress lines (the last one is always printed).
PROGRESS_INTERVAL_S = 2.0


def format_seconds(seconds: float) -> str:
    """``45s``, ``4m05s``, ``2h07m``."""
    s = max(0, int(round(seconds)))
    if s < 60:
        return f"{s}s"
    if s < 3600:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s // 3600}h{s % 3600 // 60:02d}m"


class ProgressMeter:
    """Progress lines on stderr: ``PREFIX done/total UNIT, F frames, R frames/s, eta T``.

    :meth:`update` takes the absolute count done (and frames) and prints a line when the
    first unit is done, then at most once per ``interval`` seconds, and always when all
    are done (or on :meth:`finish`). frames/s is over the time since the meter started;
    the ETA extrapolates the pace since the first unit was done (``eta ?`` before). Work found already done (a resumed job) is given
    with :meth:`resume`: it counts as done but not towards the rates. Lines go to
    ``say`` if given, else to ``stream`` (default: stderr). Thread-safe, so a callback on
    another thread may update it. Progress is for the terminal only: nothing
    of it reaches a file."""

    def __init__(self, total: int, unit: str = "episodes", *, total_frames: int | None = None,
                 interval: float = PROGRESS_INTERVAL_S, stream: Any = None,
                 say: Callable[[str], None] | None = None, clock: Callable[[], float] = time.monotonic) -> None:
        self.total, self.unit, self.total_frames = total, unit, total_frames
        self.interval, self.clock = interval, clock
        self._stream, self._say = stream, say
        self._lock = threading.Lock()
        self.start = clock()
        self.done = self.frames = 0
        self._resumed = self._resumed_frames = 0
        self._last_print: float | None = None
        self._first: tuple[float, int] | None = None  # (when, done) at the first unit done in this run
        self._last_line = ""
        self.lines = 0

    def resume(self, done: int, frames: int = 0) -> None:
        """``done`` units (``frames`` frames) were finished before this run."""
        with self._lock:
            self._resumed, self._resumed_frames = done, frames
            self.done, self.frames = max(self.done, done), max(self.frames, frames)

    def update(self, done: int, frames: int = 0, prefix: str = "", force: bool = False,
               last: bool | None = None) -> None:
        """Now ``done`` units and ``frames`` frames are done in all; print if due, or if this
        is the ``last`` update (by default: when ``done`` reaches the total)."""
        with self._lock:
            self.done, self.frames = done, frames
            now = self.clock()
            if self._first is None and done > self._resumed:
                self._first = (now, done)
            last = done >= self.total if last is None else last
            due = self._last_print is None or now - self._last_print >= self.interval
            if force or last or due:
                self._print(self.line(prefix, now), now)

    def finish(self, prefix: str = "") -> None:
        """Print the final line unless it was the last printed."""
        with self._lock:
            now = self.clock()
            line = self.line(prefix, now)
            if line != self._last_line:
                self._print(line, now)

    def line(self, prefix: str = "", now: float | None = None) -> str:
        now = self.clock() if now is None else now
        elapsed = max(now - self.start, 1e-9)
        fresh_frames = self.frames - self._resumed_frames
        frames = f"{self.frames}/{self.total_frames}" if self.total_frames is not None else f"{self.frames}"
        if self.done >= self.total:
            eta = "eta 0s"
        elif self._first is not None and self.done > self._first[1] and now > self._first[0]:
            # the pace since the first unit was done: start-up (a cluster, imports) is not work
            pace = (now - self._first[0]) / (self.done - self._first[1])
            eta = f"eta {format_seconds((self.total - self.done) * pace)}"
        else:
            eta = "eta ?"
        head = f"{prefix} " if prefix else ""
        return (f"{head}{self.done}/{self.total} {self.unit}, {frames} frames, "
                f"{max(fresh_frames, 0) / elapsed:.1f} frames/s, {eta}")

    def _print(self, line: str, now: float) -> None:
        if self._say is not None:
            self._say(line)
        else:
            print(line, file=sys.stderr if self._stream is None else self._stream, flush=True)
        self._last_print, self._last_line = now, line
        self.lines += 1


def add_json(parser: argparse.ArgumentParser, what: str = "print JSON instead of a table") -> None:
    parser.add_argument("--json", action="store_true", help=what)


# --- running ---------------------------------------------------------------------------


def _version(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--version", action="version", version=f"%(prog)s ({VERSION})")


#: Every program's ``--help`` ends with Dyana's three programs, so one leads to the others.
PROGRAMS_EPILOG = (
    "Dyana's programs: pipeline (build, eval, serve, replay, view), catalog (list, stats, specs, verify, "
    "migrate, export, info) and scoring (eval); PROGRAM COMMAND --help for each. Manual: docs/ (README.md's first screen)."
)


def make_parser(prog: str, description: str, commands: Sequence[Command]) -> OneLineParser:
    parser = OneLineParser(prog=prog, description=description, epilog=PROGRAMS_EPILOG)
    _version(parser)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True, parser_class=OneLineParser)
    for command in commands:
        p = sub.add_parser(command.name, help=command.help, description=command.help)
        _version(p)
        command.add_arguments(p)
        p.set_defaults(run=command.run)
    return parser


def _silence_stdout() -> None:
    """Point stdout at /dev/null so the interpreter's final flush cannot fail again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):
        pass


def exit_code(exc: BaseException) -> int:
    for kind, code in EXIT_CODES:
        if isinstance(exc, kind):
            return code
    if is_storage_fault(exc):  # an object store's client error that no layer translated
        return EXIT_BAD_INPUT
    raise exc


def one_line(exc: BaseException) -> str:
    """An exception as one short line (OSError by its reason and file)."""
    if isinstance(exc, OSError) and not isinstance(exc, DyanaError) and exc.strerror:
        where = f"{exc.filename}: " if exc.filename else ""
        text = f"{where}{exc.strerror}"
    else:
        text = str(exc) or type(exc).__name__
    return printable(" ".join(text.split()), MESSAGE_LIMIT)  # a peer's text may hold terminal escapes


#: URL schemes of peers and schedulers, not of storage (``--policy http://...``, ``--scheduler tcp://...``).
_PEER_SCHEMES = ("http", "https", "tcp", "tls", "ws", "wss", "inproc", "ucx", "unix", "file")


def storage_locations(args: argparse.Namespace) -> list[str]:
    """The object-store URLs a command was given (``s3://...`` in any of its arguments)."""
    found: list[str] = []
    for value in vars(args).values():
        for item in value if isinstance(value, (list, tuple)) else [value]:
            if isinstance(item, str) and "://" in item and item.split("://", 1)[0].lower() not in _PEER_SCHEMES:
                found.append(item)
    return found


def storage_line(exc: BaseException, args: argparse.Namespace) -> str:
    """An object store's failure as one line naming the URLs the command was given and the cause."""
    urls = ", ".join(shorten(url) for url in storage_locations(args))
    return printable(f"{urls + ': ' if urls else ''}{describe_storage_fault(exc)}", MESSAGE_LIMIT)


def run(prog: str, description: str, commands: Sequence[Command], argv: Sequence[str] | None = None) -> int:
    """Parse ``argv``, run the command, map failures to one line and an exit code."""
    args = make_parser(prog, description, commands).parse_args(argv)
    where = f"{prog} {args.command}"
    try:
        code = args.run(args)
        sys.stdout.flush()
        return code
    except KeyboardInterrupt:
        print(f"{where}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        _silence_stdout()
        return EXIT_BROKEN_PIPE
    except Exception as exc:
        if not isinstance(exc, DyanaError) and is_storage_fault(exc):  # before OSError: FSTimeoutError is one
            print(f"{where}: error: {storage_line(exc, args)}", file=sys.stderr)
            return EXIT_BAD_INPUT
        if not isinstance(exc, (DyanaError, OSError)):
            raise
        if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EPIPE, errno.EIO) and exc.filename is None:
            _silence_stdout()
            message = f"cannot write the output: {exc.strerror}"
        else:
            message = redact_credentials(one_line(exc))
        print(f"{where}: error: {message}", file=sys.stderr)
        return exit_code(exc)
