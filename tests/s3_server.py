"""A real S3-API server (moto's server mode) on 127.0.0.1 for the object-storage tests."""

from __future__ import annotations

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


@contextmanager
def s3_server(bucket: str) -> Iterator[dict[str, str]]:
    """Start the server, create ``bucket``, and yield the environment a client needs
    (credentials and endpoint only through the environment, as Dyana reads them)."""
    pytest.importorskip("moto.server", reason="moto[server] is not installed")
    pytest.importorskip("s3fs", reason="s3fs is not installed")
    port = _free_port()
    proc = subprocess.Popen([sys.executable, "-m", "moto.server", "-H", "127.0.0.1", "-p", str(port)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    env = {"AWS_ACCESS_KEY_ID": "dyana-test", "AWS_SECRET_ACCESS_KEY": "dyana-test-secret",
           "AWS_DEFAULT_REGION": "us-east-1", "AWS_ENDPOINT_URL": f"http://127.0.0.1:{port}"}
    try:
        deadline = time.monotonic() + 30
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
                break
            except OSError:
                if time.monotonic() > deadline or proc.poll() is not None:
                    raise RuntimeError("moto server did not start") from None
                time.sleep(0.1)
        saved = {key: os.environ.get(key) for key in env}
        os.environ.update(env)
        import fsspec
        import s3fs

        # fsspec keeps one S3 filesystem per set of arguments, made with the endpoint the
        # environment named then: a server of an earlier test would still be asked.
        s3fs.S3FileSystem.clear_instance_cache()
        try:
            fsspec.filesystem("s3", skip_instance_cache=True).mkdir(bucket)
            yield env
        finally:
            s3fs.S3FileSystem.clear_instance_cache()
            for key, value in saved.items():
                if value is None:
                    os.environ.pop(key, None)
                else:
                    os.environ[key] = value
    finally:
        proc.terminate()
        proc.wait(timeout=10)
