"""RemotePolicy: the Policy protocol spoken over a ``dyana/1`` WebSocket connection.

It connects on construction and reads the server's metadata (``name``,
``action_horizon``, ``privileged``), then forwards ``reset(task)`` and
``act(obs)``. A dropped connection, a reply later than ``timeout_s``, a malformed
reply or an ``error`` reply raises :class:`~schemas.errors.PolicyError`; after any
of these the connection is closed and the object refuses further calls (a late
reply could otherwise be mistaken for the next one): make a new RemotePolicy.
The protocol has no request ids, so replies are matched by order: a reply waiting
before a request is sent answers nothing (a server that answered one request twice).
Before an ``act`` it fails that call (the episode that got it); before a ``reset`` it
is dropped, so the next episode starts in step and the peer's fault stays in its own.
Reasons never contain the server's address, so recorded errors stay reproducible.
"""

from __future__ import annotations

import contextlib
import time
from typing import TYPE_CHECKING, Any
from urllib.parse import urlsplit

import numpy as np

from pipeline.policies.base import Observation, Task
from pipeline.remote import protocol
from schemas.errors import PolicyError, SpecError
from schemas.names import shorten

if TYPE_CHECKING:  # websockets is imported when a connection is made
    from websockets.sync.client import ClientConnection

DEFAULT_TIMEOUT_S = 30.0
OPEN_TIMEOUT_S = 10.0
_LOOPBACK = {"127.0.0.1", "localhost", "::1"}


def is_remote(ref: str) -> bool:
    """Whether a policy ref names a server (``ws://`` or ``wss://``)."""
    return isinstance(ref, str) and ref.startswith(("ws://", "wss://"))


class ServerError(PolicyError):
    """An ``error`` reply: ``message`` is the server's own text (a policy fault, as worded in process)."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(reason)
        self.message = message


class RemotePolicy:
    """A policy served at ``url``; see the module docstring."""

    def __init__(self, url: str, timeout_s: float = DEFAULT_TIMEOUT_S, open_timeout_s: float = OPEN_TIMEOUT_S) -> None:
        if not is_remote(url):
            raise SpecError(f"a remote policy URL starts with ws:// or wss://, got {shorten(repr(url))}")
        if not (isinstance(timeout_s, (int, float)) and timeout_s > 0):
            raise SpecError(f"timeout_s must be a number > 0, got {shorten(repr(timeout_s))}")
        self.url = url
        self.timeout_s = float(timeout_s)
        self.calls = 0
        self.round_trip_ms = 0.0
        self.server_ms = 0.0
        self.max_round_trip_ms = 0.0
        self._broken: str | None = None
        self._ws: ClientConnection | None = None
        self._stack = contextlib.ExitStack()
        from websockets.sync.client import connect  # lazy: websockets loads when a connection is made

        host = urlsplit(url).hostname or ""
        try:
            self._ws = self._stack.enter_context(
                connect(
                    url,
                    compression=None,
                    max_size=protocol.MAX_REPLY_BYTES,
                    open_timeout=open_timeout_s,
                    proxy=None if host in _LOOPBACK else True,
                )
            )
        except Exception as exc:  # OSError, InvalidURI, InvalidHandshake, TimeoutError, ...
            raise PolicyError(f"cannot connect to the policy server: {protocol.describe_error(exc)}") from None
        hello = self._receive(("metadata",), open_timeout_s)
        self.name: str = hello["policy"]
        self.action_horizon: int = hello["action_horizon"]
        self.privileged: bool = hello["privileged"]

    # --- Policy protocol --------------------------------------------------------------

    def reset(self, task: Task) -> None:
        while self._spare_reply() is not None:  # the previous episode's, after its last act
            pass
        self._send(protocol.reset_message(task))
        self._receive(("ready",), self.timeout_s)

    def act(self, obs: Observation) -> np.ndarray:
        spare = self._spare_reply()
        if spare is not None:
            raise self._fail(f"remote policy: protocol error: a spare {spare} reply that answers no request")
        start = time.perf_counter()
        self._send(protocol.act_message(obs))
        reply = self._receive(("action",), self.timeout_s)
        elapsed = (time.perf_counter() - start) * 1000.0
        self.calls += 1
        self.round_trip_ms += elapsed
        self.server_ms += float(reply["server_time_ms"])
        self.max_round_trip_ms = max(self.max_round_trip_ms, elapsed)
        return reply["action"]

    def close(self) -> None:
        """Close the connection (idempotent; safe from another thread while a call waits)."""
        self._stack.close()

    def __enter__(self) -> RemotePolicy:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def timing(self) -> dict[str, float]:
        """Mean round trip and server time per ``act`` (ms), the worst round trip and the call count."""
        n = max(self.calls, 1)
        return {
            "calls": self.calls,
            "round_trip_ms": self.round_trip_ms / n,
            "server_ms": self.server_ms / n,
            "max_round_trip_ms": self.max_round_trip_ms,
        }

    # --- transport ----------------------------------------------------------------------

    def _fail(self, reason: str) -> PolicyError:
        self._broken = reason
        try:
            self.close()
        except Exception:
            pass
        return PolicyError(reason)

    def _usable(self) -> ClientConnection:
        """The open connection, or PolicyError when an earlier failure closed it."""
        if self._broken is not None:
            raise PolicyError(f"remote policy unusable after an earlier failure ({self._broken})")
        if self._ws is None:
            raise PolicyError("remote policy: not connected")
        return self._ws

    def _send(self, message: dict[str, Any]) -> None:
        ws = self._usable()
        data = protocol.encode(message)
        from websockets.exceptions import ConnectionClosed

        try:
            ws.send(data)
        except ConnectionClosed as exc:
            raise self._fail(f"remote policy: connection closed ({protocol.close_reason(exc)})") from None
        except OSError as exc:
            raise self._fail(f"remote policy: cannot send ({protocol.describe_error(exc)})") from None

    def _spare_reply(self) -> str | None:
        """The type of a message already waiting (and read) when no request is pending, else None."""
        ws = self._usable()
        from websockets.exceptions import ConnectionClosed

        try:
            data = ws.recv(timeout=0)
        except TimeoutError:
            return None
        except ConnectionClosed as exc:
            raise self._fail(f"remote policy: connection closed ({protocol.close_reason(exc)})") from None
        except OSError as exc:
            raise self._fail(f"remote policy: connection failed ({protocol.describe_error(exc)})") from None
        try:
            kind = protocol.decode(data).get("type")
        except protocol.ProtocolError:
            kind = None
        return kind if isinstance(kind, str) and kind in protocol.MESSAGES else "malformed"

    def _receive(self, expected: tuple[str, ...], timeout: float) -> dict[str, Any]:
        ws = self._usable()
        from websockets.exceptions import ConnectionClosed

        try:
            data = ws.recv(timeout=timeout)
        except TimeoutError:
            raise self._fail(f"remote policy: no {' or '.join(expected)} reply within {timeout:g} s") from None
        except ConnectionClosed as exc:
            raise self._fail(f"remote policy: connection closed ({protocol.close_reason(exc)})") from None
        except OSError as exc:
            raise self._fail(f"remote policy: connection failed ({protocol.describe_error(exc)})") from None
        try:
            message = protocol.parse(data, expected)
        except protocol.ProtocolError as exc:
            raise self._fail(f"remote policy: protocol error: {exc}") from None
        if message["type"] == "error":
            self._fail(message["message"])
            raise ServerError(f"remote policy: server error: {message['message']}", message["message"])
        return message
