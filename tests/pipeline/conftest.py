"""Fixtures shared by the pipeline tests."""

from __future__ import annotations

import subprocess
import sys

import pytest


@pytest.fixture
def serve():
    """Start the loopback server in a separate process; returns its base URL."""
    started: list[subprocess.Popen] = []

    def start(mode: str = "ok", delay: float = 5.0) -> str:
        process = subprocess.Popen(
            [sys.executable, "-m", "pipeline.remote.loopback_vlm", "--mode", mode, "--delay", str(delay)],
            stdout=subprocess.PIPE, text=True,
        )
        started.append(process)
        return process.stdout.readline().strip()

    yield start
    for process in started:
        process.terminate()
        process.wait(timeout=10)
