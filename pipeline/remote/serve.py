"""`pipeline serve`: any Policy behind a ``dyana/1`` WebSocket server.

Each connection gets its own policy instance (made by the factory when the client
connects), so concurrent evaluators never share state. The server sends the
metadata message first, then answers ``reset`` with ``ready`` and ``act`` with
``action`` plus the milliseconds the policy took (``server_time_ms``). A policy
that raises, or a malformed request, gets an ``error`` message and the connection
stays open; the client decides what to do (the evaluator fails that episode).
Policy calls run on a daemon worker thread per connection, so the event loop keeps
answering pings and a policy that hangs cannot keep the server from shutting down.
The wire (:class:`Wire`) is ``dyana/1`` unless another is given (``pipeline serve
--protocol openpi``: :mod:`pipeline.remote.openpi_serve`).
"""

from __future__ import annotations

import asyncio
import signal
import sys
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

from pipeline.loop.fault_text import raised
from pipeline.loop.worker_thread import WorkerThread
from pipeline.policies.base import make_policy
from pipeline.remote import protocol
from pipeline.remote.limits import LimitError, check_images, check_task
from schemas.errors import DyanaError, PolicyError

PolicyFactory = Callable[[], Any]
#: Seconds the server waits for open sessions to end when it stops.
SHUTDOWN_GRACE_S = 5.0


@dataclass(frozen=True)
class Wire:
    """What a served protocol does around the shared session lifecycle: ``hello(policy)``
    the first message's bytes (raises when the policy cannot describe itself);
    ``answer(websocket, worker, policy)`` answers requests until the client closes;
    ``fail(websocket, text)`` reports a fault that ends the session; ``busy(websocket,
    text)`` turns away a connection beyond the limit; ``refuse(policy)`` says why a policy
    cannot be served on this wire (None: it can), checked before listening."""

    name: str
    hello: Callable[[Any], bytes]
    answer: Callable[[Any, WorkerThread, Any], Awaitable[None]]
    fail: Callable[[Any, str], Awaitable[None]]
    busy: Callable[[Any, str], Awaitable[None]]
    refuse: Callable[[Any], str | None] = lambda policy: None


def policy_factory(policy: str | PolicyFactory, wire: Wire | None = None) -> PolicyFactory:
    """A zero-argument factory from a policy name / ``module:callable`` ref, or the factory itself.

    A name is resolved once here (:func:`checked_factory`), so that a bad one fails before
    listening. (``pipeline serve`` resolves any servable kind's reference, ``lerobot:PATH``
    too, through :func:`pipeline.policy_registry.serving_factory`, then checks it here.)
    """
    if isinstance(policy, str):
        return checked_factory(lambda: make_policy(policy), wire, policy)
    if callable(policy):
        return policy
    raise DyanaError(f"serve needs a policy name, a module:callable ref or a factory, got {policy!r}")


def checked_factory(factory: PolicyFactory, wire: Wire | None, label: str) -> PolicyFactory:
    """``factory``, once the policy it makes has described itself (name, action horizon,
    privileged flag) and is one ``wire`` (default dyana/1) can serve; DyanaError naming
    ``label`` if not. The sample policy is closed."""
    wire = wire or DYANA
    sample = factory()
    try:
        protocol.check(protocol.metadata_message(sample.name, sample.action_horizon, sample.privileged))
        if not isinstance(sample.name, str) or not sample.name:
            raise protocol.ProtocolError(f"policy name must be a non-empty string, got {sample.name!r}")
        if isinstance(sample.action_horizon, bool) or not isinstance(sample.action_horizon, int):
            raise protocol.ProtocolError(f"action_horizon must be an integer >= 1, got {sample.action_horizon!r}")
        if not isinstance(sample.privileged, bool):
            raise protocol.ProtocolError(f"privileged must be True or False, got {sample.privileged!r}")
        refused = wire.refuse(sample)
        if refused:
            raise protocol.ProtocolError(refused)
    except (AttributeError, TypeError, ValueError, protocol.ProtocolError) as exc:
        raise DyanaError(f"policy {label!r} cannot be served: {_describe(exc)}") from None
    finally:
        close = getattr(sample, "close", None)
        if callable(close):
            close()
    return factory


def _describe(exc: BaseException) -> str:
    text = str(exc)
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


async def _send(websocket, message: dict[str, Any]) -> None:
    try:
        data = protocol.encode(message)
    except protocol.ProtocolError as exc:
        data = protocol.encode(protocol.error_message(f"server cannot encode its reply: {exc}"))
    await websocket.send(data)


async def _session(websocket, factory: PolicyFactory, wire: Wire) -> None:
    """One connection: the wire's hello, then its requests until the client closes."""
    from websockets.exceptions import ConnectionClosed  # lazy, as the server below

    worker = WorkerThread("dyana-serve-policy")
    policy: Any = None
    try:  # everything after the thread starts, the hello too, ends it in `finally`
        try:
            policy = await worker.acall(factory)
        except Exception as exc:
            await wire.fail(websocket, f"cannot create the policy: {_describe(exc)}")
            return
        try:
            hello = wire.hello(policy)
        except (AttributeError, TypeError, ValueError, protocol.ProtocolError) as exc:
            await wire.fail(websocket, f"the policy does not describe itself: {_describe(exc)}")
            return
        await websocket.send(hello)
        await wire.answer(websocket, worker, policy)
    except ConnectionClosed:
        pass
    finally:
        close = getattr(policy, "close", None)
        if callable(close) and not worker.stuck:
            try:
                await worker.acall(close)
            except Exception:  # a policy whose close raises must not keep its thread alive
                pass
        worker.close()


async def _answer(websocket, worker: WorkerThread, policy: Any) -> None:
    """Answer reset/act requests until the client closes."""
    reset_done = False
    resolution: int | None = None
    async for data in websocket:
        try:
            request = protocol.parse(data, ("reset", "act"))
            if request["type"] == "reset":  # what the policy would allocate for, bounded first
                check_task(request["task"])
                resolution = request["task"].get("resolution")
            elif request["type"] == "act":
                check_images(request["observation"], resolution)
        except (protocol.ProtocolError, LimitError) as exc:
            await _send(websocket, protocol.error_message(f"bad request: {exc}"))
            continue
        kind = request["type"]
        if kind == "error":
            continue
        try:
            if kind == "reset":
                await worker.acall(policy.reset, request["task"])
                reset_done = True
                reply = {"type": "ready"}
            elif not reset_done:
                reply = protocol.error_message("act before reset: send a reset message first")
            else:
                start = time.perf_counter()
                action = await worker.acall(policy.act, request["observation"])
                elapsed_ms = (time.perf_counter() - start) * 1000.0
                try:  # refused as in-process, in the same words (complex values, ...)
                    reply = protocol.action_message(action, elapsed_ms)
                except PolicyError as exc:
                    reply = protocol.error_message(str(exc))
        except Exception as exc:  # in the in-process words, traceback included
            reply = protocol.error_message(raised(kind, exc))
        await _send(websocket, reply)


async def _dyana_fail(websocket, text: str) -> None:
    await _send(websocket, protocol.error_message(text))


async def _dyana_busy(websocket, text: str) -> None:
    await _send(websocket, protocol.error_message(text))
    await websocket.close(1013, "busy")


def _dyana_hello(policy: Any) -> bytes:
    return protocol.encode(protocol.metadata_message(policy.name, policy.action_horizon, policy.privileged))


#: Dyana's own wire, dyana/1 (docs/reference/wire-protocol.md).
DYANA = Wire(protocol.PROTOCOL, _dyana_hello, _answer, _dyana_fail, _dyana_busy)


async def serve_async(
    policy: str | PolicyFactory,
    host: str = "127.0.0.1",
    port: int = 8000,
    *,
    on_listening: Callable[[str, int], None] | None = None,
    stop: asyncio.Future | None = None,
    max_message_bytes: int = protocol.MAX_MESSAGE_BYTES,
    max_connections: int = protocol.MAX_CONNECTIONS,
    wire: Wire | None = None,
    sock: Any = None,
) -> None:
    """Serve (on ``wire``, default dyana/1) until ``stop`` completes (or forever); ``on_listening(host, port)`` gets the bound port.
    ``sock``, a listening socket, is served instead of ``host:port`` (a sealed policy's: :mod:`pipeline.remote.sandbox`).

    A request over ``max_message_bytes`` closes its connection (code 1009); a connection
    beyond ``max_connections`` open at once is told the server is busy and closed (1013),
    so memory stays bounded by about their product."""
    from websockets.asyncio.server import serve as ws_serve  # lazy: importing pipeline.remote stays light

    for name, value in (("max_message_bytes", max_message_bytes), ("max_connections", max_connections)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise DyanaError(f"{name} must be an integer >= 1, got {value!r}")
    wire = wire or DYANA
    factory = policy_factory(policy, wire)
    open_sessions = 0

    async def handler(websocket) -> None:
        nonlocal open_sessions
        if open_sessions >= max_connections:
            await wire.busy(websocket, f"server busy: at most {max_connections} connections at once")
            return
        open_sessions += 1
        try:
            await _session(websocket, factory, wire)
        finally:
            open_sessions -= 1

    try:
        where: dict[str, Any] = {"host": host, "port": port} if sock is None else {"sock": sock}
        server = await ws_serve(
            handler,
            **where,
            compression=None,
            max_size=max_message_bytes,
            ping_interval=20,
            ping_timeout=60,
        )
    except OSError as exc:
        raise DyanaError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None
    try:
        bound = server.sockets[0].getsockname()[1] if server.sockets else port
        if on_listening is not None:
            on_listening(host, bound)
        if stop is None:
            await server.serve_forever()
        else:
            await stop
    finally:
        server.close()
        try:  # a session stuck in a hung policy call must not block shutdown
            await asyncio.wait_for(server.wait_closed(), SHUTDOWN_GRACE_S)
        except TimeoutError:
            pass


def serve(
    policy: str | PolicyFactory,
    host: str = "127.0.0.1",
    port: int = 8000,
    *,
    max_message_bytes: int = protocol.MAX_MESSAGE_BYTES,
    max_connections: int = protocol.MAX_CONNECTIONS,
    wire: Wire | None = None,
    sock: Any = None,
    label: str | None = None,
) -> None:
    """Serve ``policy`` on ``ws://host:port`` (or the listening ``sock``; ``wire``, default dyana/1)
    until SIGINT/SIGTERM; prints the address on stderr, naming the policy ``label`` (default:
    its reference or factory's name)."""
    wire = wire or DYANA

    def listening(bound_host: str, bound_port: int) -> None:
        name = label or (policy if isinstance(policy, str) else getattr(policy, "__name__", "policy"))
        print(f"serving {name} on ws://{bound_host}:{bound_port} ({wire.name})", file=sys.stderr, flush=True)

    async def main() -> None:
        loop = asyncio.get_running_loop()
        stop: asyncio.Future[None] = loop.create_future()

        def request_stop() -> None:
            if not stop.done():
                stop.set_result(None)

        for sig in (signal.SIGINT, signal.SIGTERM):
            try:
                loop.add_signal_handler(sig, request_stop)
            except (NotImplementedError, RuntimeError):
                pass
        await serve_async(
            policy, host, port, on_listening=listening, stop=stop,
            max_message_bytes=max_message_bytes, max_connections=max_connections, wire=wire, sock=sock,
        )

    asyncio.run(main())
