"""A deterministic stand-in VLM server, for trying ``pipeline eval --policy vlm:...`` offline
and for the tests: the OpenAI chat-completions API on 127.0.0.1, whose "model" reads the
current image with the predictive baseline's perception (no model weights needed).

It is a real HTTP server implementing ``POST /v1/chat/completions`` (and
``GET /v1/models``) that answers ``{"palm_target": [...], "closure": c}`` for the object
it sees in the last image of the request, with the hand state read back from the prompt
(it aims over the object and closes once the palm is within reach). ``--mode`` makes it
misbehave instead, one fault per mode: ``malformed`` (no JSON), ``prose`` (JSON inside
prose and a code fence), ``error`` (HTTP 500), ``slow`` (answers after ``--delay``
seconds), ``refuse`` (the API's ``refusal`` field), ``flaky`` (HTTP 500 on every third
request).

    python -m pipeline.remote.loopback_vlm --port 8011            # prints its URL
    pipeline eval --policy vlm:http://127.0.0.1:8011/v1 --model loopback-perception ...
"""

from __future__ import annotations

import argparse
import base64
import functools
import json
import re
import sys
import threading
import time
import zlib
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

import cv2
import numpy as np

from generators.hand import REST_JOINTS, forward_kinematics
from pipeline.policies.perception import ObjectLocator
from schemas.scene import LOC_TOLERANCE, PALM_HOVER

MODES = ("ok", "malformed", "prose", "error", "slow", "refuse", "flaky", "drip", "huge", "bomb", "long")
LONG_CHARS = 2**20
HUGE_BYTES = 64 * 2**20
BOMB_BYTES = 100 * 2**20
MODEL = "loopback-perception"
_PALM = re.compile(r"palm centre at \[([-\d.]+), ([-\d.]+), ([-\d.]+)\]")
_TASK = re.compile(r"Task: (.*)")


def _images(message: dict[str, Any]) -> list[np.ndarray]:
    out = []
    for part in message.get("content", []):
        if isinstance(part, dict) and part.get("type") == "image_url":
            data = part["image_url"]["url"].split(",", 1)[1]
            image = cv2.imdecode(np.frombuffer(base64.b64decode(data), np.uint8), cv2.IMREAD_COLOR)
            if image is not None:
                out.append(np.ascontiguousarray(image[:, :, ::-1]))
    return out


def _text(message: dict[str, Any]) -> str:
    content = message.get("content", "")
    if isinstance(content, str):
        return content
    return "\n".join(p.get("text", "") for p in content if isinstance(p, dict) and p.get("type") == "text")


def perceive(text: str, images: list[np.ndarray]) -> dict[str, Any]:
    """The loopback model's answer: aim over the object seen in the last image, close when there."""
    palm_match, task_match = _PALM.search(text), _TASK.search(text)
    palm = np.array([float(v) for v in palm_match.groups()]) if palm_match else np.zeros(3)
    task = task_match.group(1) if task_match else ""
    if not images:
        return {"palm_target": [round(float(v), 4) for v in palm], "closure": 0.0}
    image = images[-1]
    locator = ObjectLocator(task, image.shape[0])
    pose = np.concatenate([palm, np.zeros(3)])
    joint_poses, keypoints = forward_kinematics(pose[None], REST_JOINTS[None], "right")
    seen = None
    for frame in images:  # the first frame teaches the locator the table's colour
        seen = locator.locate(frame, pose, joint_poses[0], keypoints[0])
    if seen is None:
        return {"palm_target": [round(float(v), 4) for v in palm], "closure": 0.0}
    x, z = float(seen.position[0]), float(seen.position[2])
    target = [round(x, 4), round(float(locator.top_height + PALM_HOVER), 4), round(z, 4)]
    close = float(np.hypot(palm[0] - x, palm[2] - z)) <= LOC_TOLERANCE
    return {"palm_target": target, "closure": 1.0 if close else 0.0}


@functools.cache
def _bomb() -> bytes:
    """A gzip body of :data:`BOMB_BYTES` of spaces (it compresses ~1000:1)."""
    packer = zlib.compressobj(9, zlib.DEFLATED, 16 + zlib.MAX_WBITS)
    block = b" " * 2**20
    return b"".join([*(packer.compress(block) for _ in range(BOMB_BYTES // len(block))), packer.flush()])


class _Handler(BaseHTTPRequestHandler):
    server: LoopbackServer

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 - the base class's name
        return None

    def _send(self, status: int, body: dict[str, Any]) -> None:
        data = json.dumps(body).encode()
        mode = self.server.mode
        if mode == "huge" and status == 200:
            data = data[:-1] + b" " * HUGE_BYTES + b"}"
        encoding = None
        if mode == "bomb" and status == 200:
            data, encoding = _bomb(), "gzip"
        if mode == "drip":
            head = f"HTTP/1.0 {status} OK\r\nContent-Type: application/json\r\nContent-Length: {len(data)}\r\n\r\n"
            for byte in head.encode() + data:
                self.wfile.write(bytes([byte]))
                self.wfile.flush()
                time.sleep(self.server.delay)
            return
        self.send_response(status)
        self.send_header("Content-Type", "application/json")
        if encoding:
            self.send_header("Content-Encoding", encoding)
        self.send_header("Content-Length", str(len(data)))
        self.end_headers()
        self.wfile.write(data)

    def handle_one_request(self) -> None:
        try:
            super().handle_one_request()
        except (BrokenPipeError, ConnectionResetError):  # a client that stopped reading (a bounded one)
            self.close_connection = True

    def do_GET(self) -> None:  # noqa: N802 - http.server's name
        if self.path.rstrip("/").endswith("/models"):
            self._send(200, {"object": "list", "data": [{"id": MODEL, "object": "model", "owned_by": "dyana"}]})
        else:
            self._send(404, {"error": {"message": "not found"}})

    def do_POST(self) -> None:  # noqa: N802
        if not self.path.rstrip("/").endswith("/chat/completions"):
            self._send(404, {"error": {"message": f"no route {self.path}"}})
            return
        length = int(self.headers.get("Content-Length", "0"))
        try:
            request = json.loads(self.rfile.read(length))
        except ValueError:
            self._send(400, {"error": {"message": "the body is not JSON"}})
            return
        self.server.count += 1
        mode = self.server.mode
        if mode == "error" or (mode == "flaky" and self.server.count % 3 == 0):
            self._send(500, {"error": {"message": "the loopback server failed on purpose"}})
            return
        if mode == "slow":
            time.sleep(self.server.delay)
        message = request["messages"][-1]
        text, images = _text(message), _images(message)
        refusal = None
        if mode == "refuse":
            content, refusal = None, "I can't help with controlling robots."
        elif mode == "malformed":
            content = "palm_target: somewhere over the ball, closure: maybe"
        else:
            answer = json.dumps(perceive(text, images))
            content = f"Here is my plan.\n```json\n{answer}\n```\nGood luck." if mode == "prose" else answer
            if mode == "long":
                content = "Let me think. " * (LONG_CHARS // 13) + answer
        usage = {"prompt_tokens": len(text.split()) + 85 * len(images), "completion_tokens": len((content or "").split())}
        usage["total_tokens"] = usage["prompt_tokens"] + usage["completion_tokens"]
        self._send(200, {
            "id": f"loopback-{self.server.count}",
            "object": "chat.completion",
            "created": 0,
            "model": request.get("model", MODEL),
            "choices": [{"index": 0, "finish_reason": "stop",
                         "message": {"role": "assistant", "content": content, "refusal": refusal}}],
            "usage": usage,
        })


class LoopbackServer(ThreadingHTTPServer):
    """The server; ``url`` is its OpenAI base URL (``http://127.0.0.1:PORT/v1``)."""

    daemon_threads = True

    def __init__(self, port: int = 0, mode: str = "ok", delay: float = 5.0) -> None:
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        super().__init__(("127.0.0.1", port), _Handler)
        self.mode, self.delay, self.count = mode, delay, 0

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.server_address[1]}/v1"

    def start(self) -> LoopbackServer:
        threading.Thread(target=self.serve_forever, daemon=True).start()
        return self


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="A loopback OpenAI-compatible VLM stand-in (perception-based).")
    parser.add_argument("--port", type=int, default=0, help="port on 127.0.0.1 (default: any free one)")
    parser.add_argument("--mode", choices=MODES, default="ok")
    parser.add_argument("--delay", type=float, default=5.0, help="seconds the slow mode waits")
    args = parser.parse_args(argv)
    server = LoopbackServer(args.port, args.mode, args.delay)
    print(server.url, flush=True)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
