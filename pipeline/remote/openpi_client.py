"""OpenpiPolicy: an openpi policy server (``openpi:ws://HOST:PORT``) as a Dyana policy.

openpi's protocol (``openpi_client.websocket_client_policy``): on connect the server sends
its metadata (a map); then each request is an observation dict and each reply a dict
with ``"actions"``; a server that fails sends the error (a traceback) as a *text* frame
and closes the connection. There is no reset message: ``reset(task)`` sends nothing and
the next request carries the task under ``dyana/task`` (:mod:`pipeline.remote.openpi_keys`).
A reply later than ``timeout_s``, a dropped connection, a malformed reply, actions not of
shape (H, 18) or an error frame raise :class:`~schemas.errors.PolicyError`, close the
connection and make the object refuse further calls (the evaluator fails that episode and
connects anew for the next). Reasons never contain the server's address.
"""

from __future__ import annotations

import contextlib
import time
from typing import TYPE_CHECKING, Any
from urllib.parse import parse_qsl, urlsplit, urlunsplit

import numpy as np

from pipeline.policies.base import Observation, Task
from pipeline.remote import openpi_wire
from pipeline.remote.openpi_keys import OpenpiConfig, chunk_from, request_for
from pipeline.remote.protocol import MAX_REPLY_BYTES, ProtocolError, close_reason, describe_error
from schemas.errors import PolicyError, SpecError
from schemas.names import shorten

if TYPE_CHECKING:  # websockets is imported when a connection is made
    from websockets.sync.client import ClientConnection

PREFIX = "openpi:"
OPEN_TIMEOUT_S = 10.0
_LOOPBACK = {"127.0.0.1", "localhost", "::1"}


def split_ref(ref: str) -> tuple[str, OpenpiConfig]:
    """``openpi:ws://HOST:PORT[/PATH][?key=value&...]`` -> the server's URL (without the
    query) and the configuration the query sets; SpecError names a bad part."""
    if not isinstance(ref, str) or not ref.startswith(PREFIX):
        raise SpecError(f"an openpi policy is openpi:ws://HOST:PORT, got {shorten(repr(ref), 80)}")
    url = ref[len(PREFIX):]
    try:
        parts = urlsplit(url)  # raises on an unclosed [IPv6 address
        if parts.scheme not in ("ws", "wss") or not parts.hostname:
            raise SpecError(f"an openpi policy is openpi:ws://HOST:PORT (or wss://), got {shorten(repr(ref), 80)}")
        parts.port  # noqa: B018  # raises on a port out of range
        pairs = parse_qsl(parts.query, keep_blank_values=True, strict_parsing=bool(parts.query))
    except ValueError as exc:
        raise SpecError(f"openpi policy {shorten(repr(ref), 80)}: {exc}") from None
    return urlunsplit((parts.scheme, parts.netloc, parts.path, "", "")), OpenpiConfig.from_pairs(pairs)


class OpenpiPolicy:
    """The policy an openpi server at ``url`` serves; see the module docstring."""

    privileged = False

    def __init__(self, url: str, config: OpenpiConfig, timeout_s: float, open_timeout_s: float = OPEN_TIMEOUT_S) -> None:
        if not isinstance(config, OpenpiConfig):
            raise SpecError(f"config must be an OpenpiConfig, got {type(config).__name__}")
        if isinstance(timeout_s, bool) or not isinstance(timeout_s, (int, float)) or not timeout_s > 0:
            raise SpecError(f"timeout_s must be a number > 0, got {shorten(repr(timeout_s))}")
        self.config = config
        self.timeout_s = float(timeout_s)
        self.calls = 0
        self.round_trip_ms = self.server_ms = self.max_round_trip_ms = 0.0
        self._task: dict[str, Any] | None = None
        self._broken: str | None = None
        self._stack = contextlib.ExitStack()
        from websockets.sync.client import connect  # lazy: websockets loads when a connection is made

        host = urlsplit(url).hostname or ""
        try:
            self._ws: ClientConnection = self._stack.enter_context(connect(
                url, compression=None, max_size=MAX_REPLY_BYTES, open_timeout=open_timeout_s,
                proxy=None if host in _LOOPBACK else True,
            ))
        except Exception as exc:  # OSError, InvalidURI, InvalidHandshake, TimeoutError, ...
            raise PolicyError(f"cannot connect to the openpi server: {describe_error(exc)}") from None
        self.metadata = self._receive("metadata", open_timeout_s)
        served = self.metadata.get("policy")
        self.name: str = config.name or (served if isinstance(served, str) and served else "openpi")
        horizon = self.metadata.get("action_horizon")
        if config.steps is not None:
            self.action_horizon: int = config.steps
        elif isinstance(horizon, int) and not isinstance(horizon, bool) and horizon >= 1:
            self.action_horizon = horizon
        else:
            self.action_horizon = 1

    def reset(self, task: Task) -> None:
        self._usable()
        self._task = dict(task)

    def act(self, obs: Observation) -> np.ndarray:
        ws = self._usable()
        try:
            spare = ws.recv(timeout=0)
        except TimeoutError:
            spare = None
        except Exception as exc:
            raise self._fail(f"openpi policy: connection lost ({describe_error(exc)})") from None
        if spare is not None:
            what = "an error frame: " + openpi_wire.error_line(spare) if isinstance(spare, str) else "a reply"
            raise self._fail(f"openpi policy: protocol error: {what} that answers no request")
        try:
            data = openpi_wire.encode(request_for(obs, self._task, self.config))
        except (KeyError, TypeError, ValueError) as exc:
            raise self._fail(f"openpi policy: cannot build the request: {describe_error(exc)}") from None
        start = time.perf_counter()
        try:
            ws.send(data)
        except Exception as exc:  # ConnectionClosed, OSError
            raise self._fail(f"openpi policy: cannot send ({describe_error(exc)})") from None
        self._task = None
        reply = self._receive("reply", self.timeout_s)
        elapsed = (time.perf_counter() - start) * 1000.0
        try:
            chunk = chunk_from(reply, self.config)
        except PolicyError as exc:
            raise self._fail(str(exc)) from None
        timing = reply.get("server_timing")
        infer_ms = timing.get("infer_ms") if isinstance(timing, dict) else None
        self.calls += 1
        self.round_trip_ms += elapsed
        self.server_ms += float(infer_ms) if isinstance(infer_ms, (int, float)) and not isinstance(infer_ms, bool) else 0.0
        self.max_round_trip_ms = max(self.max_round_trip_ms, elapsed)
        return chunk

    def timing(self) -> dict[str, float]:
        """Mean round trip and server time per ``act`` (ms), the worst round trip and the call count."""
        n = max(self.calls, 1)
        return {"calls": self.calls, "round_trip_ms": self.round_trip_ms / n, "server_ms": self.server_ms / n,
                "max_round_trip_ms": self.max_round_trip_ms}

    def close(self) -> None:
        """Close the connection (idempotent)."""
        self._stack.close()

    def __enter__(self) -> OpenpiPolicy:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def _usable(self) -> ClientConnection:
        if self._broken is not None:
            raise PolicyError(f"openpi policy unusable after an earlier failure ({self._broken})")
        return self._ws

    def _fail(self, reason: str) -> PolicyError:
        self._broken = reason
        with contextlib.suppress(Exception):
            self.close()
        return PolicyError(reason)

    def _receive(self, what: str, timeout: float) -> dict[str, Any]:
        from websockets.exceptions import ConnectionClosed

        try:
            data = self._usable().recv(timeout=timeout)
        except TimeoutError:
            raise self._fail(f"openpi policy: no {what} within {timeout:g} s") from None
        except ConnectionClosed as exc:
            raise self._fail(f"openpi policy: connection closed ({close_reason(exc)})") from None
        except OSError as exc:
            raise self._fail(f"openpi policy: connection failed ({describe_error(exc)})") from None
        if isinstance(data, str):  # openpi's server reports a failure as a text frame, then closes
            raise self._fail(f"openpi policy: server error: {openpi_wire.error_line(data)}")
        try:
            return openpi_wire.decode(data)
        except ProtocolError as exc:
            raise self._fail(f"openpi policy: protocol error in the {what}: {exc}") from None
