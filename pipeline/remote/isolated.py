"""A user's policy run in a child process, so that its death fails only its episode.

``pipeline eval --policy module:callable`` runs the callable under ``pipeline serve`` in
a child process on 127.0.0.1 and talks to it over the same ``dyana/1`` protocol as
any remote policy (byte-identical to running it in process). Whatever the policy does
to its own process (``os._exit``, ``sys.exit``, an uncaught ``KeyboardInterrupt``, a
kill for memory, a segfault in native code) ends that process only: the episode is
recorded as an error naming how the process ended, and the next episode gets a fresh
process. What the policy prints goes nowhere near eval's output.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
from collections import deque

import numpy as np

from pipeline.policies.base import Observation, Task
from pipeline.remote.client import RemotePolicy, ServerError
from schemas.errors import PolicyError
from schemas.names import printable

#: Seconds a child process has to import the policy and start listening.
START_TIMEOUT_S = 120.0


def _ended(code: int) -> str:
    if code < 0:
        try:
            return f"was killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"was killed by signal {-code}"
    return f"exited with code {code}"


class IsolatedPolicy:
    """The Policy protocol over a child ``pipeline serve`` process (see the module docstring)."""

    def __init__(self, ref: str, timeout_s: float) -> None:
        self.ref = ref
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(p or os.getcwd() for p in sys.path)}
        command = [sys.executable, "-m", "pipeline.cli", "serve", "--policy", ref, "--host", "127.0.0.1",
                   "--port", "0", "--max-connections", "1"]
        self._process = subprocess.Popen(
            command, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env,
            start_new_session=True,
        )
        self._last_lines: deque[str] = deque(maxlen=3)
        url = self._wait_for_url()
        self._drain = threading.Thread(target=self._drain_stderr, name="dyana-policy-stderr", daemon=True)
        self._drain.start()
        try:
            self._remote = RemotePolicy(url, timeout_s=timeout_s)
        except PolicyError as exc:
            self.close()
            raise PolicyError(f"isolated policy {ref!r}: {exc}") from None
        self.name = self._remote.name
        self.action_horizon = self._remote.action_horizon
        self.privileged = self._remote.privileged

    def _wait_for_url(self) -> str:
        stderr = self._process.stderr
        assert stderr is not None
        timer = threading.Timer(START_TIMEOUT_S, self._process.kill)
        timer.start()
        try:
            for raw in stderr:
                line = raw.decode("utf-8", "replace").strip()
                self._last_lines.append(line)
                if line.startswith("serving ") and " on ws://" in line:
                    return line.split(" on ", 1)[1].split()[0]
        finally:
            timer.cancel()
        code = self._process.wait()
        detail = printable(self._last_lines[-1], 200) if self._last_lines else "no output"
        raise PolicyError(f"the policy process for {self.ref!r} {_ended(code)} before serving: {detail}")

    def _drain_stderr(self) -> None:
        stderr = self._process.stderr
        assert stderr is not None
        for raw in stderr:
            self._last_lines.append(raw.decode("utf-8", "replace").strip()[:200])

    def _failure(self, exc: PolicyError) -> PolicyError:
        """The fault in the words of an in-process run: the policy's own error as is (no
        wait: its process is alive), else how the process ended, if it did."""
        if isinstance(exc, ServerError):
            return PolicyError(exc.message)
        text = str(exc).removeprefix("remote policy: ")
        try:
            code = self._process.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            return PolicyError(f"policy process: {text}")
        return PolicyError(f"policy process {_ended(code)} ({text})")

    def reset(self, task: Task) -> None:
        try:
            self._remote.reset(task)
        except PolicyError as exc:
            raise self._failure(exc) from None

    def act(self, obs: Observation) -> np.ndarray:
        try:
            return self._remote.act(obs)
        except PolicyError as exc:
            raise self._failure(exc) from None

    def timing(self) -> dict[str, float]:
        return self._remote.timing()

    def close(self) -> None:
        """Close the connection and end the child process (killed if it does not stop)."""
        remote = getattr(self, "_remote", None)
        if remote is not None:
            remote.close()
        if self._process.poll() is None:
            self._process.terminate()
            try:
                self._process.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                self._process.kill()
                self._process.wait()
