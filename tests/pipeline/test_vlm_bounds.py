"""Bounds of a VLM exchange against hostile endpoints on 127.0.0.1 (the loopback server's
``drip``, ``huge`` and ``bomb`` modes) and hostile answers: time, bytes, depth, each fault
in the trail."""

from __future__ import annotations

import contextlib
import signal
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


def test_a_dripping_reply_is_cut_at_the_timeout(serve):
    """One byte every 50 ms (the status line too): each read is quick, the whole is not."""
    reply, elapsed, _ = _complete(serve("drip", delay=0.05), timeout_s=1.0)
    assert reply.outcome == "timeout", reply
    assert elapsed < 1.8  # the timeout and some slack (on the old code: ~15 s)


@pytest.mark.parametrize("mode, said", [("huge", "bytes"), ("bomb", "once decompressed")])
def test_a_reply_over_the_byte_limit_is_refused_reading_a_bounded_amount(serve, mode, said):
    reply, _, peak = _complete(serve(mode), timeout_s=10.0, trace=True)
    assert reply.outcome == "http_error" and "reply too large" in reply.detail and said in reply.detail, reply
    assert f"{MAX_REPLY_BYTES:,}" in reply.detail
    assert peak < 4 * MAX_REPLY_BYTES, f"{peak:,} bytes held"


def test_a_bomb_fails_its_act_and_is_in_the_trail(serve, tmp_path):
    import io

    from pipeline.jobs.evaluate import evaluate

    run = tmp_path / "run"
    evaluate(f"vlm:{serve('bomb')}", "test-1k", run, episodes=1, workers=0, resolution=64, shard_size=1,
             progress=False, summary=False, stream=io.StringIO(), config={"model": "loopback-perception"})
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


def test_a_long_answer_is_stored_as_a_prefix_with_its_size_and_hash_and_replays(serve, tmp_path):
    import hashlib
    import io

    from pipeline.jobs.evaluate import evaluate
    from pipeline.jobs.replay import replay
    from pipeline.remote.loopback_vlm import LONG_CHARS

    run = tmp_path / "run"
    evaluate(f"vlm:{serve('long')}", "test-1k", run, episodes=1, workers=0, resolution=64, shard_size=1,
             progress=False, summary=False, stream=io.StringIO(), config={"model": "loopback-perception"})
    [record] = read_audit(run / "vlm")
    reply = record["reply"]
    assert record["outcome"] == "parse_error" and "at most 65,536" in record["detail"]
    assert len(reply["content"]) == MAX_ANSWER_CHARS and reply["content_chars"] > LONG_CHARS
    assert len(reply["content_sha256"]) == 64 and reply["content_sha256"] != hashlib.sha256(b"").hexdigest()
    assert sum(p.stat().st_size for p in (run / "vlm").iterdir()) < 2 * MAX_ANSWER_CHARS
    assert replay(run).episodes == 1


def test_an_unreachable_endpoint_is_refused_before_the_first_episode(tmp_path, capsys):
    import socket

    from pipeline.cli import main as pipeline_main

    with socket.socket() as closed:  # a port nothing listens on
        closed.bind(("127.0.0.1", 0))
        port = closed.getsockname()[1]
    out = tmp_path / "run"
    start = time.monotonic()
    code = pipeline_main(["eval", "--policy", f"vlm:http://user:pw@127.0.0.1:{port}/v1", "--model", "m", "--slice",
                          "test-1k", "--episodes", "2", "--workers", "1", "--repeats", "2", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and time.monotonic() - start < 8
    assert err.count("\n") == 1 and f"vlm:http://127.0.0.1:{port}/v1: cannot reach the VLM endpoint" in err, err
    assert "pw" not in err and not out.exists()
