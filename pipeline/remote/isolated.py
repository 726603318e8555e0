"""A user's policy run in a child process, so that its death fails only its episode.

``pipeline eval --policy module:callable`` runs the callable under ``pipeline serve`` in
a child process on 127.0.0.1 and talks to it over the same ``dyana/1`` protocol as
any remote policy (byte-identical to running it in process). Whatever the policy does
to its own process (``os._exit``, ``sys.exit``, an uncaught ``KeyboardInterrupt``, a
kill for memory, a segfault in native code) ends that process only: the episode is
recorded as an error naming how the process ended, and the next episode gets a fresh
process. What the policy prints goes nowhere near eval's output.

The child's parent is a small launcher (:mod:`pipeline.remote.launcher`), not the eval
worker, and the child runs in a session of its own: a policy that signals its parent
(``os.kill(os.getppid(), SIGKILL)``) or its process group reaches no Dyana process; its
episode fails at that call, naming the signal. The policy's process group (its own
children too) ends when the policy is closed, and when the eval dies, even by SIGKILL.
With a :class:`~pipeline.remote.sandbox.Seal` (a held-out run) the process is sealed in
namespaces of its own (:mod:`pipeline.remote.sandbox`).
"""

from __future__ import annotations

import os
import sys
import threading
from collections import deque

import numpy as np

from pipeline.policies.base import Observation, Task
from pipeline.remote import sandbox
from pipeline.remote.client import RemotePolicy, ServerError
from pipeline.remote.launcher import Launched
from pipeline.remote.sandbox import Seal
from schemas.errors import PolicyError
from schemas.names import printable, shorten

#: Seconds a child process has to import the policy and start listening.
START_TIMEOUT_S = 120.0


class IsolatedPolicy:
    """The Policy protocol over a child ``pipeline serve`` process (see the module docstring)."""

    def __init__(self, ref: str, timeout_s: float, seal: Seal | None = None) -> None:
        self.ref = ref
        if seal is None:
            env = {**os.environ, "PYTHONPATH": os.pathsep.join(p or os.getcwd() for p in sys.path)}
            command = [sys.executable, "-m", "pipeline.cli", "serve", "--policy", ref, "--host", "127.0.0.1",
                       "--port", "0", "--max-connections", "1"]
            self._process = Launched(command, env)
        else:  # sealed (pipeline.remote.sandbox): it serves a socket made here, in its own namespaces
            with sandbox.listening_socket() as sock:
                self._process = Launched(sandbox.command(seal, ref, sock.fileno()), sandbox.environment(),
                                         pass_fd=sock.fileno())
        self._last_lines: deque[str] = deque(maxlen=3)
        url = self._wait_for_url()
        self._drain = threading.Thread(target=self._drain_stderr, name="dyana-policy-stderr", daemon=True)
        self._drain.start()
        try:
            self._remote = RemotePolicy(url, timeout_s=timeout_s)
        except PolicyError as exc:
            self.close()
            raise PolicyError(f"isolated policy {shorten(repr(ref))}: {exc}") from None
        self.name = self._remote.name
        self.action_horizon = self._remote.action_horizon
        self.privileged = self._remote.privileged

    def _wait_for_url(self) -> str:
        timer = threading.Timer(START_TIMEOUT_S, self._process.kill)
        timer.start()
        try:
            if self._process.started() is not None:
                for raw in self._process.stderr:
                    line = raw.decode("utf-8", "replace").strip()
                    self._last_lines.append(line)
                    if line.startswith("serving ") and " on ws://" in line:
                        return line.split(" on ", 1)[1].split()[0]
        finally:
            timer.cancel()
        stop = self._process.end(START_TIMEOUT_S)
        self._process.close()
        detail = printable(self._last_lines[-1], 200) if self._last_lines else "no output"
        ended = "did not start" if stop is None else stop.text
        raise PolicyError(f"the policy process for {self.ref!r} {ended} before serving: {detail}")

    def _drain_stderr(self) -> None:
        for raw in self._process.stderr:
            self._last_lines.append(raw.decode("utf-8", "replace").strip()[:200])

    def _failure(self, exc: PolicyError) -> PolicyError:
        """The fault in the words of an in-process run: the policy's own error as is (no
        wait: its process is alive), else how the process ended, if it did."""
        if isinstance(exc, ServerError):
            return PolicyError(exc.message)
        text = str(exc).removeprefix("remote policy: ")
        stop = self._process.end(2.0)
        if stop is None:
            return PolicyError(f"policy process: {text}")
        if stop.by_parent:  # the cause, in the same words whether the call or the check failed
            return PolicyError(f"policy process {stop.text}")
        return PolicyError(f"policy process {stop.text} ({text})")

    def _checked(self) -> None:
        """PolicyError when the policy signalled its parent (or its process ended) during the call."""
        stop = self._process.check()
        if stop is not None:
            raise PolicyError(f"policy process {stop.text}")

    def reset(self, task: Task) -> None:
        try:
            self._remote.reset(task)
        except PolicyError as exc:
            raise self._failure(exc) from None
        self._checked()

    def act(self, obs: Observation) -> np.ndarray:
        try:
            action = self._remote.act(obs)
        except PolicyError as exc:
            raise self._failure(exc) from None
        self._checked()
        return action

    def timing(self) -> dict[str, float]:
        return self._remote.timing()

    def close(self) -> None:
        """Close the connection, then end the child process and its process group (see the launcher)."""
        remote = getattr(self, "_remote", None)
        if remote is not None:
            remote.close()
        self._process.close()
