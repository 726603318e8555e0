"""A real S3-API server (moto's server mode) on 127.0.0.1 for the object-storage tests."""

from __future__ import annotations

import atexit
import importlib.util
import os
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager

import pytest


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


#: This process's server (started by the first test that asks, ended when the process exits).
_running: dict[str, object] = {}


def _server_port() -> int:
    """The port of this process's moto server, started on first use (one per test process:
    each start took ~1.7 CPU s, and up to four modules of the default run ask for one)."""
    proc = _running.get("proc")
    if isinstance(proc, subprocess.Popen) and proc.poll() is None:
        return int(str(_running["port"]))
    port = _free_port()
    proc = subprocess.Popen([sys.executable, "-m", "moto.server", "-H", "127.0.0.1", "-p", str(port)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    atexit.register(_stop, proc)
    deadline = time.monotonic() + 30
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
            break
        except OSError:
            if time.monotonic() > deadline or proc.poll() is not None:
                _stop(proc)
                raise RuntimeError("moto server did not start") from None
            time.sleep(0.1)
    _running.update(proc=proc, port=port)
    return port


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.terminate()
        proc.wait(timeout=10)


@contextmanager
def s3_server(bucket: str) -> Iterator[dict[str, str]]:
    """The server, with ``bucket`` made empty, and the environment a client needs
    (credentials and endpoint only through the environment, as Dyana reads them)."""
    for module in ("moto.server", "s3fs"):
        if importlib.util.find_spec(module) is None:  # not importorskip: no need to import them here
            pytest.skip(f"{module} is not installed (moto[server] and s3fs are)")
    port = _server_port()
    env = {"AWS_ACCESS_KEY_ID": "dyana-test", "AWS_SECRET_ACCESS_KEY": "dyana-test-secret",
           "AWS_DEFAULT_REGION": "us-east-1", "AWS_ENDPOINT_URL": f"http://127.0.0.1:{port}"}
    saved = {key: os.environ.get(key) for key in env}
    os.environ.update(env)
    import fsspec
    import s3fs

    # fsspec keeps one S3 filesystem per set of arguments, made with the endpoint the
    # environment named then: a server of an earlier test would still be asked.
    s3fs.S3FileSystem.clear_instance_cache()
    try:
        fs = fsspec.filesystem("s3", skip_instance_cache=True)
        if fs.exists(bucket):  # an earlier test in this process used it: start empty, as on a new server
            fs.rm(bucket, recursive=True)
            fs.invalidate_cache()
        fs.mkdir(bucket)
        yield env
    finally:
        s3fs.S3FileSystem.clear_instance_cache()
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
