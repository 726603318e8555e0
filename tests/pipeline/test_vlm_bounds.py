"""Bounds of a VLM exchange against hostile endpoints on 127.0.0.1 (the loopback server's
``drip``, ``huge`` and ``bomb`` modes) and hostile answers: time, bytes, depth, each fault
in the trail."""

from __future__ import annotations

import contextlib
import signal
import subprocess
import sys
import time
import tracemalloc
from collections.abc import Iterator

import pytest

from pipeline.jobs.audit import read_audit
from pipeline.policies.vlm_answer import MAX_ANSWER_CHARS, AnswerError, parse_answer
from pipeline.policies.vlm_http import MAX_REPLY_BYTES
from pipeline.policies.vlm_transport import HttpTransport, Reply

REQUEST = {"model": "loopback-perception", "messages": [{"role": "user", "content": "hi"}]}


@contextlib.contextmanager
def within(seconds: float) -> Iterator[None]:
    """Fail (TimeoutError) when the block runs longer than ``seconds`` (a pure-Python loop is interrupted)."""

    def expire(signum: int, frame: object) -> None:
        raise TimeoutError(f"took more than {seconds} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


@pytest.fixture
def hostile():
    started: list[subprocess.Popen] = []

    def start(mode: str, delay: float = 0.05) -> str:
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


def _complete(url: str, timeout_s: float, trace: bool = False) -> tuple[Reply, float, int]:
    """One exchange: the reply, its wall time and (``trace``) the peak Python memory it took."""
    transport = HttpTransport(url, "DYANA_TEST_UNSET_KEY", timeout_s)
    if trace:
        tracemalloc.start()
    start = time.monotonic()
    try:
        reply = transport.complete(REQUEST)
    finally:
        elapsed = time.monotonic() - start
        peak = tracemalloc.get_traced_memory()[1] if trace else 0
        tracemalloc.stop()
        transport.close()
    return reply, elapsed, peak


def test_a_dripping_reply_is_cut_at_the_timeout(hostile):
    """One byte every 50 ms (the status line too): each read is quick, the whole is not."""
    reply, elapsed, _ = _complete(hostile("drip", delay=0.05), timeout_s=1.0)
    assert reply.outcome == "timeout", reply
    assert elapsed < 1.8  # the timeout and some slack (on the old code: ~15 s)


@pytest.mark.parametrize("mode, said", [("huge", "bytes"), ("bomb", "once decompressed")])
def test_a_reply_over_the_byte_limit_is_refused_reading_a_bounded_amount(hostile, mode, said):
    reply, _, peak = _complete(hostile(mode), timeout_s=10.0, trace=True)
    assert reply.outcome == "http_error" and "reply too large" in reply.detail and said in reply.detail, reply
    assert f"{MAX_REPLY_BYTES:,}" in reply.detail
    assert peak < 4 * MAX_REPLY_BYTES, f"{peak:,} bytes held"


def test_a_bomb_fails_its_act_and_is_in_the_trail(hostile, tmp_path):
    import io

    from pipeline.jobs.evaluate import evaluate

    run = tmp_path / "run"
    evaluate(f"vlm:{hostile('bomb')}", "test-1k", run, episodes=1, workers=0, resolution=64, shard_size=1,
             progress=False, summary=False, stream=io.StringIO(), vlm={"model": "loopback-perception"})
    [record] = read_audit(run / "vlm")
    assert record["outcome"] == "http_error" and "reply too large" in record["detail"]


@pytest.mark.parametrize("content", [
    "{" * 40_000,
    '{"a": ' * 5_000 + "1" + "}" * 5_000,
    '{"palm_target": ' + "[" * 20_000,
    "{ " * (MAX_ANSWER_CHARS // 2),
])
def test_hostile_answers_fail_fast_as_parse_errors(content):
    with within(1.0), pytest.raises(AnswerError) as caught:
        parse_answer(content)
    assert caught.value.kind == "parse_error"


def test_an_answer_over_the_length_limit_is_not_read():
    answer = '{"palm_target": [1, 2, 3], "closure": 0.5}'
    with pytest.raises(AnswerError, match="at most 65,536"):
        parse_answer(answer + " " * MAX_ANSWER_CHARS)
    assert parse_answer("x" * 1000 + answer).closure == 0.5
