"""The parent of an isolated policy's process: the parent a policy sees (and may signal), not Dyana.

:class:`Launched` (the eval worker's side) starts ``python -m pipeline.remote.launcher
COMMAND...`` in a session of its own; the launcher starts COMMAND (``pipeline serve``)
in another session, so the policy's ``os.getppid()`` is the launcher and no process group
it can name holds a Dyana process. The launcher ends the policy's whole process group
(its children too) whenever it stops:

- its stdin (a pipe from the worker) reaches end of file: the worker closed the policy,
  or died (even by SIGKILL, which runs no clean-up): SIGTERM, then SIGKILL after
  :data:`GRACE_S`;
- it gets any signal that would stop it (the policy sent its parent SIGTERM, SIGINT,
  ...): SIGKILL at once, and the reason is reported;
- the policy's process ends: the rest of its group gets SIGKILL, and how it ended is
  reported.

A SIGKILL to the launcher cannot be caught: the policy's process then gets SIGKILL from
the kernel (``PR_SET_PDEATHSIG``, Linux) and the worker ends what is left of its group.

The launcher speaks to the worker on its stdout: ``pid N`` (the policy's process) first,
one ``+`` for each ``?`` read from stdin (the worker asks after every policy call, and a
signal the policy sent during the call is seen before the answer, so the episode fails
at that call on every run), and last ``!exit HOW`` (the policy's process ended by itself)
or ``!parent WHY`` (the launcher stopped it), nothing when the worker closed it. It
imports only the standard library, so it starts in a few tens of milliseconds.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import select
import signal
import subprocess
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import IO

#: Seconds the policy's process group has to end after SIGTERM before it gets SIGKILL.
GRACE_S = 5.0
#: Seconds the worker waits for the launcher's answer to a check (it answers at once).
CHECK_TIMEOUT_S = 10.0
#: Seconds between the launcher's looks at pending signals while nothing is asked.
POLL_S = 0.05
#: Signals that do nothing by default, or that the launcher cannot or need not watch.
UNWATCHED = {signal.SIGKILL, signal.SIGSTOP, signal.SIGPIPE, signal.SIGCONT, signal.SIGWINCH, signal.SIGURG}
PR_SET_PDEATHSIG = 1


def ended(code: int) -> str:
    """How a process ended, from its return code: ``exited with code 3``, ``was killed by SIGKILL``."""
    if code < 0:
        try:
            return f"was killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"was killed by signal {-code}"
    return f"exited with code {code}"


def _signal_name(number: int) -> str:
    try:
        return signal.Signals(number).name
    except ValueError:
        return f"signal {number}"


def _kill_group(pgid: int, sig: int) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(pgid, sig)


def _in_group(pid: int, pgid: int) -> bool:
    try:
        return pid == pgid or os.getpgid(pid) == pgid
    except OSError:
        return False


Prctl = Callable[[int, int], int]


def _child_setup(parent: int, prctl: Prctl | None) -> None:
    """In the policy's process before exec: every signal unblocked, SIGKILL when the launcher dies."""
    signal.pthread_sigmask(signal.SIG_SETMASK, set())
    if prctl is not None:
        prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != parent:  # the launcher died before the line above
        os._exit(1)


def _libc_prctl() -> Prctl | None:
    """libc's prctl (Linux), or None where there is none."""
    try:
        prctl: Prctl = ctypes.CDLL(None, use_errno=True).prctl
        return prctl
    except (AttributeError, OSError):
        return None


def _stop(child: subprocess.Popen[bytes], graceful: bool) -> None:
    """End the policy's process group: SIGTERM and a grace period first when ``graceful``."""
    if graceful and child.poll() is None:
        _kill_group(child.pid, signal.SIGTERM)
        with contextlib.suppress(subprocess.TimeoutExpired):
            child.wait(GRACE_S)
    _kill_group(child.pid, signal.SIGKILL)
    child.wait()


def _watch(child: subprocess.Popen[bytes], watched: set[signal.Signals]) -> tuple[str | None, bool]:
    """Serve the worker's checks until the launcher must stop: (the report, ``exit ...`` or
    ``parent ...``, or None when the worker closed; whether to stop gracefully)."""
    while True:
        readable = select.select([0], [], [], POLL_S)[0]
        while (info := signal.sigtimedwait(watched, 0)) is not None:  # before any answer: see the module docstring
            if info.si_signo == signal.SIGCHLD:
                continue
            name = _signal_name(info.si_signo)
            if _in_group(info.si_pid, child.pid):
                return f"parent sent {name} to its parent process, which a policy must not do; it was stopped", False
            return f"parent was stopped: its parent process got {name} from another process", False
        code = child.poll()
        if code is not None:
            return f"exit {ended(code)}", False
        if readable:
            asked = os.read(0, 4096)
            if not asked:
                return None, True
            os.write(1, b"+" * asked.count(b"?"))


def main(argv: Sequence[str]) -> int:
    """Run ``argv`` as the policy's process under this launcher (see the module docstring);
    ``--pass-fd N`` first passes that open descriptor on (a sealed policy's listening socket)."""
    watched = set(signal.valid_signals()) - UNWATCHED
    signal.pthread_sigmask(signal.SIG_BLOCK, watched)
    passed: tuple[int, ...] = ()
    if len(argv) > 2 and argv[0] == "--pass-fd" and argv[1].isdigit():
        passed, argv = (int(argv[1]),), argv[2:]
    if not argv:
        print("usage: python -m pipeline.remote.launcher [--pass-fd N] COMMAND...", file=sys.stderr)
        return 2
    me, prctl = os.getpid(), _libc_prctl()
    child = subprocess.Popen(
        list(argv), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, start_new_session=True,
        preexec_fn=lambda: _child_setup(me, prctl), pass_fds=passed,
    )
    report: str | None = None
    graceful = True
    try:
        os.write(1, f"pid {child.pid}\n".encode())
        report, graceful = _watch(child, watched)
    except OSError:  # the worker's end of a pipe is gone: it died
        pass
    finally:
        _stop(child, graceful)
    if report is not None:
        with contextlib.suppress(OSError):
            os.write(1, f"!{report}\n".encode())
    return 0


@dataclass(frozen=True)
class Stop:
    """How a policy's process stopped: ``text`` follows "policy process" (``exited with code 3``);
    ``by_parent`` when the launcher stopped it (the policy signalled its parent, or it died)."""

    text: str
    by_parent: bool

    def __post_init__(self) -> None:
        if not self.text:
            raise ValueError(f"a Stop needs a text, got {self.text!r}")


class Launched:
    """A command run as a policy's process under the launcher: the worker's side (above)."""

    def __init__(self, command: Sequence[str], env: dict[str, str], pass_fd: int | None = None) -> None:
        passing = [] if pass_fd is None else ["--pass-fd", str(pass_fd)]
        self._launcher = subprocess.Popen(
            [sys.executable, "-m", "pipeline.remote.launcher", *passing, *command], stdin=subprocess.PIPE,
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, start_new_session=True,
            pass_fds=() if pass_fd is None else (pass_fd,),
        )
        self._out = bytearray()
        self._ended: Stop | None = None
        self.pid: int | None = None

    @property
    def stderr(self) -> IO[bytes]:
        """What the policy's process (and the launcher) print on stderr."""
        stderr = self._launcher.stderr
        assert stderr is not None
        return stderr

    def _read(self, timeout: float | None) -> bool:
        """Add what the launcher wrote to the buffer; False at end of file or after ``timeout`` s."""
        stdout = self._launcher.stdout
        assert stdout is not None
        if not select.select([stdout], [], [], timeout)[0]:
            return False
        data = os.read(stdout.fileno(), 4096)
        self._out.extend(data)
        return bool(data)

    def started(self) -> int | None:
        """The policy's process id (None if the launcher ended without starting it)."""
        while b"\n" not in self._out and self._read(None):
            pass
        if self._out.startswith(b"pid ") and b"\n" in self._out:
            line, _, rest = bytes(self._out).partition(b"\n")
            self.pid, self._out = int(line[4:]), bytearray(rest)
        return self.pid

    def check(self) -> Stop | None:
        """None while the policy's process runs and has not signalled its parent; else how it stopped."""
        stdin = self._launcher.stdin
        assert stdin is not None
        with contextlib.suppress(OSError):  # a launcher gone is told by end()
            os.write(stdin.fileno(), b"?")
            if self._out or self._read(CHECK_TIMEOUT_S):
                if self._out[:1] == b"+":
                    del self._out[:1]
                    return None
        return self.end(CHECK_TIMEOUT_S) or Stop("was stopped: its parent process does not answer", True)

    def end(self, timeout: float) -> Stop | None:
        """How the policy's process stopped, once the launcher has ended (None if it runs after ``timeout`` s)."""
        try:
            code = self._launcher.wait(timeout)
        except subprocess.TimeoutExpired:
            return None
        while self._read(0):
            pass
        if self._ended is None:
            kind, _, text = bytes(self._out).lstrip(b"+").decode("utf-8", "replace").strip().partition(" ")
            if kind in ("!exit", "!parent") and text:
                self._ended = Stop(text, kind == "!parent")
            else:
                hint = " (a policy must not signal its parent)" if code < 0 else ""
                self._ended = Stop(f"was stopped: its parent process {ended(code)}{hint}", True)
        return self._ended
    def close(self) -> None:
        """End the policy's process group (gracefully first) and the launcher, waiting for both."""
        stdin = self._launcher.stdin
        if stdin is not None:
            with contextlib.suppress(OSError):
                stdin.close()
        try:
            clean = self._launcher.wait(GRACE_S + 2.0) == 0
        except subprocess.TimeoutExpired:  # stopped (SIGSTOP) or stuck: end it
            self._launcher.kill()
            self._launcher.wait()
            clean = False
        if not clean and self.pid is not None:  # the launcher could not end the group itself
            _kill_group(self.pid, signal.SIGKILL)
        stdout = self._launcher.stdout
        if stdout is not None:
            stdout.close()

    def kill(self) -> None:
        """End the launcher and the policy's process group at once (a start that took too long)."""
        self._launcher.kill()
        if self.pid is not None:
            _kill_group(self.pid, signal.SIGKILL)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
