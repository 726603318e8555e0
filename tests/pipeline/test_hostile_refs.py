"""Policy references and URLs from input: a credential in a URL is never printed, and every
malformed reference is one line and exit 2, never a traceback (issue 39's findings)."""

from __future__ import annotations

import pytest

from pipeline.cli import main
from schemas.names import printable, redact_credentials, shorten


@pytest.mark.parametrize("text, want", [
    ("ws://user:S3CRET@127.0.0.1:9/x", "ws://user:***@127.0.0.1:9/x"),
    ("cannot reach openpi:wss://u:p@host and s3://k:s@bucket/x", "cannot reach openpi:wss://u:***@host and s3://k:***@bucket/x"),
    ("http://TOKEN@host/", "http://***@host/"),
    ("mail me at a@b.c, see ws://host:1/x", "mail me at a@b.c, see ws://host:1/x"),
])
def test_credentials_in_urls_are_redacted(text, want):
    assert redact_credentials(text) == want
    assert shorten(text, 400) == want and printable(text, 400) == want


def test_a_password_across_the_cut_of_a_long_value_is_still_hidden():
    text = "ws://user:" + "S3CRET" * 30 + "@host"
    assert "S3CRET" not in shorten(text, 40) and "S3CRET" not in printable(text, 40)


@pytest.mark.parametrize("ref, message", [
    ("openpi:ws://user:S3CRETPW@127.0.0.1:9", "openpi:ws://user:***@127.0.0.1:9: cannot connect to the openpi server"),
    ("ws://user:S3CRETPW@127.0.0.1:9", "ws://user:***@127.0.0.1:9: cannot connect to the policy server"),
    ("openpi:ws://user:S3CRETPW@[::1", "Invalid IPv6 URL"),
    ("openpi:ws://127.0.0.1:9?steps=\u00b2", "openpi steps must be an integer >= 1"),
    ("openpi:ws://127.0.0.1:9?steps=" + "9" * 5000, "openpi steps must be an integer >= 1"),
    ("lerobot:~nosuchuser-dyana/ckpt", "its ~user is not a user here"),
    ("lerobot:{deep}", "config.json: unreadable (nested too deeply)"),
])
def test_bad_policy_refs_are_one_line_without_the_password(tmp_path, capsys, ref, message):
    deep = tmp_path / "deep"
    deep.mkdir()
    (deep / "config.json").write_text("[" * 100_000 + "]" * 100_000)
    (deep / "model.safetensors").write_bytes(b"")
    code = main(["eval", "--policy", ref.format(deep=deep), "--slice", "linear-fast", "--episodes", "1",
                 "--out", str(tmp_path / "run")])  # in process: a traceback would raise here
    out = capsys.readouterr()
    lines = out.err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and message in lines[0], out.err
    assert "S3CRETPW" not in out.err + out.out


@pytest.mark.parametrize("command", [["eval", "--policy", "still", "--slice", "test-1k", "--episodes", "1"], ["replay"]])
def test_a_test_seed_file_that_is_a_fifo_is_refused_at_once(tmp_path, capsys, command):
    import os
    import time

    fifo = tmp_path / "secret"
    os.mkfifo(fifo)  # no writer: reading it would block for ever
    argv = [command[0], *([str(tmp_path)] if command[0] == "replay" else ["--out", str(tmp_path / "run")]), *command[1:]]
    start = time.monotonic()
    code = main([*argv, "--test-seed-file", str(fifo)])
    err = capsys.readouterr().err
    assert code == 2 and "--test-seed-file" in err and "a FIFO, not a regular file" in err, err
    assert time.monotonic() - start < 30


def test_an_openpi_key_of_undecodable_bytes_is_refused_before_serving(capsys):
    """Before: `pipeline serve --openpi-key image=$'\\xff'` started serving, then failed every connection."""
    import os

    code = main(["serve", "--policy", "still", "--protocol", "openpi", "--port", "0",
                 "--openpi-key", "image=" + os.fsdecode(b"obs/\xff")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "openpi key names are printable UTF-8 text" in err, err
