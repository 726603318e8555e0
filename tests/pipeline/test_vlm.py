"""VLM controllers against real HTTP servers on 127.0.0.1 (the loopback chat-completions
server in its honest and misbehaving modes): answers, faults, audit trail, replay."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest

import catalog
from pipeline.cli import main as pipeline_main
from pipeline.jobs.audit import read_audit
from pipeline.jobs.evaluate import evaluate
from pipeline.jobs.replay import replay
from pipeline.policies.vlm_answer import AnswerError, parse_answer
from schemas.errors import ShardError
from scoring.cli import main as scoring_main

RESOLUTION = 64
SECRET = "sk-dyana-test-secret-never-written"


def _eval(url: str, out: Path, episodes: int = 2, **vlm) -> None:
    options = {"model": "loopback-perception", "timeout_s": 10.0, **vlm}
    evaluate(f"vlm:{url}", "test-1k", out, episodes=episodes, workers=1, resolution=RESOLUTION, shard_size=2,
             progress=False, summary=False, stream=io.StringIO(), config=options)


@pytest.mark.parametrize("content, expected", [
    ('{"palm_target": [1, 2, 3], "closure": 0.5}', {"palm_target": [1.0, 2.0, 3.0], "closure": 0.5}),
    ('Sure!\n```json\n{"palm_target": [0, 1.5, 4], "closure": 1.7}\n```', {"palm_target": [0.0, 1.5, 4.0], "closure": 1.0}),
    ('{"palm_target": [0, 1, 2], "joint_angles": [0.1, 0.2, 0.3, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]}',
     {"palm_target": [0.0, 1.0, 2.0], "joint_angles": [0.1, 0.2, 0.3] + [0.0] * 12}),
])
def test_answers_are_read_leniently(content, expected):
    assert parse_answer(content).to_dict() == expected


@pytest.mark.parametrize("content, refusal, finish, kind", [
    ("I'm sorry, I can't help with that.", None, "stop", "refusal"),
    (None, "No.", "stop", "refusal"),
    ('{"palm_target": [1, 2, 3], "closure": 0}', None, "content_filter", "refusal"),
    ("move left a bit", None, "stop", "parse_error"),
    ('{"palm_target": [1, 2], "closure": 0}', None, "stop", "parse_error"),
    ('{"palm_target": [1, 2, "x"], "closure": 0}', None, "stop", "parse_error"),
    ('{"palm_target": [1, 2, 3], "closure": NaN}', None, "stop", "parse_error"),
    ('{"palm_target": [1, 2, 3]', None, "stop", "parse_error"),
    ('{"palm_target": [' + "9" * 5000 + ', 2, 3], "closure": 0}', None, "stop", "parse_error"),  # was a ValueError
])
def test_unusable_answers_name_their_kind(content, refusal, finish, kind):
    with pytest.raises(AnswerError) as caught:
        parse_answer(content, refusal, finish)
    assert caught.value.kind == kind


def test_a_vlm_run_keeps_its_trail_scores_and_replays_without_the_endpoint(serve, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("OPENAI_API_KEY", SECRET)
    url = serve("ok")
    run = tmp_path / "run"
    _eval(url, run, episodes=4)
    manifest = json.loads((run / "catalog.json").read_text())
    assert manifest["policy"] == "vlm:loopback-perception"
    assert manifest["vlm"]["template"] == "v1" and len(manifest["vlm"]["template_sha256"]) == 64
    records = read_audit(run / "vlm")
    assert records and {r["outcome"] for r in records} == {"ok"}
    assert {r["episode_id"] for r in records} == {f"test-1k:{i:06d}" for i in range(4)}
    first = [r for r in records if r["query"] == 1]
    assert all(r["images"][-1] == {"frame": r["frame_index"]} for r in records)
    assert any(len(r["images"]) > 1 for r in first), "the first query carries observe-window frames"
    assert all(r["reply"]["usage"]["prompt_tokens"] > 0 for r in records)
    for path in [*run.rglob("*.json"), *run.rglob("*.jsonl")]:
        text = path.read_text()
        assert SECRET not in text and "base64" not in text, path
    assert scoring_main(["eval", str(run), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["episodes"] == 4
    monkeypatch.setenv("OPENAI_API_KEY", "")
    report = replay(run)  # the server may be gone: replay reads the trail
    assert report.episodes == 4


def test_a_changed_trail_is_refused_by_replay(serve, tmp_path):
    run = tmp_path / "run"
    _eval(serve("ok"), run, episodes=2)
    trail = next((run / "vlm").glob("audit-*.jsonl"))
    trail.write_text(trail.read_text().replace('"closure": 0.0', '"closure": 1.0'))
    with pytest.raises(ShardError, match="changed since the run"):
        replay(run)


@pytest.mark.parametrize("mode, kind", [("malformed", "parse_error"), ("error", "http_error"), ("refuse", "refusal"),
                                        ("slow", "timeout")])
def test_each_fault_fails_only_its_episode_with_the_reason(serve, tmp_path, mode, kind):
    run = tmp_path / "run"
    _eval(serve(mode, delay=3.0), run, episodes=2, timeout_s=1.0)
    with catalog.open(run) as ds:
        assert [e.status for e in ds.episodes] == ["error", "error"]
    assert [r["outcome"] for r in read_audit(run / "vlm")] == [kind, kind]
    from catalog.tables.reader import open_folder

    errors = open_folder(run).episodes(["error"]).column("error").to_pylist()
    assert all(f"vlm {kind} at frame" in e for e in errors), errors


def test_hold_keeps_going_through_faults_and_counts_them(serve, tmp_path):
    run = tmp_path / "run"
    _eval(serve("flaky"), run, episodes=2, on_fault="hold")
    with catalog.open(run) as ds:
        assert [e.status for e in ds.episodes] == ["ok", "ok"]
    outcomes = [r["outcome"] for r in read_audit(run / "vlm")]
    assert outcomes.count("http_error") == len(outcomes) // 3 and outcomes.count("ok") > 0
    assert replay(run).episodes == 2


@pytest.mark.slow(cover="tests/pipeline/test_protocols.py::test_latency_delays_every_action_by_n_frames_and_the_hand_holds_meanwhile")
def test_latency_is_simulated_deterministically(serve, tmp_path):
    url = serve("prose")
    for name in ("a", "b"):
        _eval(url, tmp_path / name, episodes=2, latency_frames=3, every=4)
    a, b = (json.loads((tmp_path / n / "catalog.json").read_text())["hash"] for n in ("a", "b"))
    assert a == b
    with catalog.open(tmp_path / "a") as ds:
        actions = np.stack([ds[i]["action"] for i in ds.episode_frames(1)])
        first_act = ds.episodes[1].observe_frames
    # answers take effect 3 frames after they were asked: the first acting frames hold the rest pose
    np.testing.assert_array_equal(actions[first_act], actions[first_act + 2])


def test_the_cli_needs_a_model_and_keeps_vlm_flags_to_vlm_policies(tmp_path, capsys):
    assert pipeline_main(["eval", "--policy", "vlm:http://127.0.0.1:9/v1", "--out", str(tmp_path / "r")]) == 2
    assert "--model NAME" in capsys.readouterr().err
    assert pipeline_main(["eval", "--policy", "still", "--model", "x", "--out", str(tmp_path / "r")]) == 2
    assert "--model is for --policy vlm:URL only" in capsys.readouterr().err
    assert pipeline_main(["eval", "--policy", "vlm:ftp://x", "--model", "m", "--out", str(tmp_path / "r")]) == 2
    assert "http://" in capsys.readouterr().err


@pytest.mark.parametrize(
    "flag, value, named",
    [
        ("--vlm-latency-frames", "1000000000", "latency_frames must be an integer in [0, 1000]"),
        ("--vlm-observe-images", "1000000000", "observe_images must be an integer in [0, 16]"),
        ("--vlm-temperature", "-1", "temperature must be a finite number in [0, 2]"),
        ("--vlm-temperature", "nan", "temperature must be a finite number in [0, 2]"),
        ("--vlm-temperature", "inf", "temperature must be a finite number in [0, 2]"),
        ("--vlm-seed", str(2**70), "seed must be an integer in [0, 9223372036854775807]"),
        ("--vlm-api-key-env", "", "api_key_env must name an environment variable"),
        ("--vlm-api-key-env", "sk-a key", "api_key_env must name an environment variable"),
    ],
)
def test_vlm_settings_out_of_bounds_are_refused_naming_them(tmp_path, capsys, flag, value, named):
    out = tmp_path / "r"
    code = pipeline_main(["eval", "--policy", "vlm:http://127.0.0.1:9/v1", "--model", "m", flag, value, "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and named in err and err.count("\n") == 1, err
    assert not out.exists()


@pytest.fixture
def echo_endpoint():
    """An endpoint that echoes the Authorization header into its answer (or, as ``/fail``,
    into an HTTP 500 body) and reports NaN token counts."""
    import threading
    from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

    class Echo(BaseHTTPRequestHandler):
        def log_message(self, *args):
            pass

        def do_POST(self):  # noqa: N802
            self.rfile.read(int(self.headers.get("Content-Length", 0)))
            auth = self.headers.get("Authorization", "")
            broken = {"/deep": "[" * 5000 + "]" * 5000, "/empty": "", "/null": "null", "/bad": "{not json",
                      "/nullmsg": json.dumps({"id": "x", "object": "chat.completion", "created": 0, "model": "m",
                                              "choices": [{"index": 0, "message": None, "finish_reason": "stop"}]})}
            if self.path.split("/v1")[0] in broken:
                body, status = broken[self.path.split("/v1")[0]], 200
            elif self.path.startswith("/fail"):
                body, status = json.dumps({"error": {"message": f"bad header {auth}"}}), 500
            else:
                message = {"role": "assistant", "content": f"you sent {auth}"}
                body = json.dumps({"id": "x", "object": "chat.completion", "created": 0, "model": "m",
                                   "choices": [{"index": 0, "message": message, "finish_reason": "stop"}],
                                   "usage": {"prompt_tokens": float("nan"), "completion_tokens": 1e400,
                                             "total_tokens": 1}})
                status = 200
            data = body.encode()
            self.send_response(status)
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(data)))
            self.end_headers()
            self.wfile.write(data)

    server = ThreadingHTTPServer(("127.0.0.1", 0), Echo)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    yield f"http://127.0.0.1:{server.server_address[1]}"
    server.shutdown()


@pytest.mark.parametrize("path", ["/v1", "/fail/v1"])
def test_an_endpoint_echoing_the_key_never_gets_it_stored(echo_endpoint, monkeypatch, path):
    """The key (and any Bearer credential) is redacted from every text of a reply, and
    usage that is not a whole number is dropped, so the audit trail can be written."""
    from pipeline.policies.vlm_transport import HttpTransport

    monkeypatch.setenv("DYANA_TEST_KEY", SECRET)
    transport = HttpTransport(echo_endpoint + path, "DYANA_TEST_KEY", 10.0)
    try:
        reply = transport.complete({"model": "m", "messages": [{"role": "user", "content": "hi"}]})
    finally:
        transport.close()
    stored = json.dumps(reply.to_dict(), allow_nan=False)
    assert SECRET not in stored and "sk-dyana" not in stored
    assert "Bearer [redacted]" in stored
    if path == "/v1":
        assert reply.outcome == "answered" and reply.prompt_tokens is None and reply.completion_tokens is None
    else:
        assert reply.outcome == "http_error"


@pytest.mark.parametrize("path", ["/deep", "/empty", "/null", "/bad", "/nullmsg"])
def test_an_unreadable_reply_is_an_http_error_reply_not_an_exception(echo_endpoint, path):
    """Invalid JSON, an empty or null body, a null message, 5,000-deep JSON: the transport
    returns an http_error reply (so the trail records it), it does not raise."""
    from pipeline.policies.vlm_transport import HttpTransport

    transport = HttpTransport(echo_endpoint + path + "/v1", "DYANA_TEST_UNSET_KEY", 10.0)
    try:
        reply = transport.complete({"model": "m", "messages": [{"role": "user", "content": "hi"}]})
    finally:
        transport.close()
    assert reply.outcome == "http_error" and ("unreadable reply" in reply.detail or "malformed reply" in reply.detail)
    json.dumps(reply.to_dict(), allow_nan=False)
