"""`pipeline serve --protocol openpi`: a Dyana policy for openpi clients.

As openpi's own server (``openpi.serving.websocket_policy_server``): on connect the server
sends its metadata (a map: ``policy``, ``action_horizon``, ``keys``); then it answers each
request (an observation dict, :mod:`pipeline.remote.openpi_keys`) with ``{"actions": (H, 18)
float32, "server_timing": {"infer_ms": ...}}``. A malformed request or a policy that raises
gets a *text* frame (the fault, its last line the reason) and the connection is closed with
code 1011, as openpi does. openpi has no reset message: the policy is reset (with the
request's ``dyana/task``, else a task built from the request) before the first request of a
connection and before every request that carries ``dyana/task``.
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from typing import Any

from pipeline.loop.fault_text import raised, split_reason
from pipeline.loop.worker_thread import WorkerThread
from pipeline.remote import openpi_wire, protocol
from pipeline.remote.limits import LimitError, check_images, check_task
from pipeline.remote.openpi_keys import TASK, OpenpiConfig, observation_from, reply_for, task_from
from pipeline.remote.serve import Wire
from schemas.errors import PolicyError, SpecError

NAME = "openpi"
#: Settings of the client side only (``openpi:ws://...?steps=N``), refused by the server.
CLIENT_ONLY = ("extras", "steps", "name")


async def _fail(websocket, text: str) -> None:
    """openpi's way: the fault as a text frame, then close (1011)."""
    await websocket.send(text)
    await websocket.close(1011, "policy server error: see the previous frame")


async def _busy(websocket, text: str) -> None:
    await websocket.send(text)
    await websocket.close(1013, "busy")


def _fault_text(what: str, exc: BaseException) -> str:
    """A policy fault as openpi's server words it: a traceback whose last line is the reason."""
    head, frames = split_reason(raised(what, exc))
    return "\n".join(["Traceback (the policy's frames):", *frames, head]) if frames else head


def _refuse(policy: Any) -> str | None:
    if policy.privileged:
        return f"policy {policy.name!r} is privileged (it reads the episode's spec), which openpi's wire does not carry"
    return None


def openpi_wire_for(settings: Iterable[tuple[str, str]] = ()) -> Wire:
    """The openpi wire with the key names ``settings`` set (``--openpi-key NAME=KEY``)."""
    pairs = list(settings)
    for key, _ in pairs:
        if key in CLIENT_ONLY:
            raise SpecError(f"--openpi-key {key}=... is a client setting (openpi:ws://HOST:PORT?{key}=...), not a server one")
    config = OpenpiConfig.from_pairs(pairs)

    def hello(policy: Any) -> bytes:
        described = protocol.check(protocol.metadata_message(policy.name, policy.action_horizon, policy.privileged))
        return openpi_wire.encode({"policy": described["policy"], "action_horizon": described["action_horizon"],
                                   "keys": config.wire_keys()})

    async def answer(websocket, worker: WorkerThread, policy: Any) -> None:
        started = False
        resolution: int | None = None
        async for data in websocket:
            try:
                request = openpi_wire.decode(data)
                obs = observation_from(request, config)
                check_images(obs, None)  # what the policy would allocate for, bounded first
                task = task_from(request, obs) if not started or TASK in request else None
                if task is not None:
                    check_task(task)
                    resolution = task.get("resolution")
                check_images(obs, resolution)
            except (protocol.ProtocolError, LimitError) as exc:
                await _fail(websocket, f"bad request: {exc}")
                return
            what = "reset"
            try:
                if task is not None:
                    await worker.acall(policy.reset, task)
                    started = True
                what = "act"
                start = time.perf_counter()
                action = await worker.acall(policy.act, obs)
                infer_ms = (time.perf_counter() - start) * 1000.0
            except Exception as exc:  # in the in-process words, the policy's frames included
                await _fail(websocket, _fault_text(what, exc))
                return
            try:  # refused as in-process, in the same words (complex values, ...)
                reply = openpi_wire.encode(reply_for(action, infer_ms, config))
            except PolicyError as exc:
                await _fail(websocket, str(exc))
                return
            await websocket.send(reply)

    return Wire(NAME, hello, answer, _fail, _busy, _refuse)
