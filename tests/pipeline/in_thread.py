"""Test helpers that run Dyana somewhere else than the test's own call stack: a policy
server in a thread of this process, and a tests module's function in a fresh interpreter."""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]


@contextmanager
def served(policy: Any, **options: Any) -> Iterator[str]:
    """``pipeline.remote.serve.serve_async(policy, ...)`` on 127.0.0.1, a free port, in a daemon
    thread: its ``ws://`` URL while the block runs; the server is stopped after it."""
    from pipeline.remote.serve import serve_async

    ready, holder = threading.Event(), {}

    async def main() -> None:
        loop = asyncio.get_running_loop()
        holder["loop"], holder["stop"] = loop, loop.create_future()

        def listening(host: str, port: int) -> None:
            holder["url"] = f"ws://{host}:{port}"
            ready.set()

        await serve_async(policy, "127.0.0.1", 0, on_listening=listening, stop=holder["stop"], **options)

    thread = threading.Thread(target=lambda: asyncio.run(main()), daemon=True)
    thread.start()
    try:
        assert ready.wait(30)
        yield holder["url"]
    finally:
        holder["loop"].call_soon_threadsafe(holder["stop"].set_result, None)
        thread.join(30)


def fresh_json(module: str, function: str, hash_seed: str) -> Any:
    """``module.function()``'s JSON-able result computed in a fresh interpreter (this checkout
    first on its path, a minimal environment, ``PYTHONHASHSEED`` set): what another process gives."""
    code = (f"import json, sys; sys.path.insert(0, {str(ROOT)!r}); "
            f"from {module} import {function}; print(json.dumps({function}()))")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                            env={"PYTHONHASHSEED": hash_seed, "PATH": "/usr/bin:/bin"})
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout.strip().splitlines()[-1])
