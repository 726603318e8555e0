"""Runs in the openpi-client venv (numpy<2, no Dyana): an openpi policy server written as
openpi's own (metadata first, a dict with "actions" per request, a failure as a text frame
then close 1011), packing and unpacking with openpi_client's msgpack_numpy.

    python server.py      # prints "listening PORT", serves until killed

The policy holds the hand still: each reply is a chunk of 10 identical rows, the palm
position and joint angles of the request's "observation/state" (palm pose 6 + joints 15)."""

import asyncio
import time
import traceback

import numpy as np
import websockets
import websockets.asyncio.server
import websockets.frames
from openpi_client import msgpack_numpy


async def handler(ws):
    packer = msgpack_numpy.Packer()
    await ws.send(packer.pack({"policy": "still", "peer": "openpi-client"}))
    while True:
        try:
            obs = msgpack_numpy.unpackb(await ws.recv())
            start = time.monotonic()
            state = np.asarray(obs["observation/state"], dtype=np.float32)
            row = np.concatenate([state[:3], state[6:21]])
            reply = {"actions": np.tile(row, (10, 1)), "server_timing": {"infer_ms": 1000 * (time.monotonic() - start)}}
            await ws.send(packer.pack(reply))
        except websockets.ConnectionClosed:
            break
        except Exception:
            await ws.send(traceback.format_exc())
            await ws.close(code=websockets.frames.CloseCode.INTERNAL_ERROR, reason="see the previous frame")
            break


async def main():
    async with websockets.asyncio.server.serve(handler, "127.0.0.1", 0, compression=None, max_size=None) as server:
        print("listening", server.sockets[0].getsockname()[1], flush=True)
        await server.serve_forever()


asyncio.run(main())
