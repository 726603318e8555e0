"""Object-store URLs and endpoints from input (issue 39's findings): a URL no reader would
find again or that carries a control character is refused before any work, an endpoint
that never answers times out, and a reply cut short is one line."""

from __future__ import annotations

import socket
import threading
import time

import pytest

import catalog.store.s3_session
import catalog.store.storage
from catalog.store.storage import as_location, where
from pipeline.cli_catalog import main as catalog_main
from schemas.errors import SpecError
from schemas.storage_faults import describe_storage_fault, is_storage_fault

from .test_object_store import no_aws  # noqa: F401  # the fixture


@pytest.mark.parametrize("url", ["s3://bucket//x", "s3://bucket/a//b/", "s3://bucket/\x1b[2Jx"])
def test_a_url_with_an_empty_folder_or_a_control_character_is_refused(url):
    with pytest.raises(SpecError, match="has an empty folder name or a control character") as refused:
        as_location(url, "out")
    assert "\x1b" not in str(refused.value)


def test_where_never_prints_an_escape_sequence():
    assert where("s3://bucket/\x1b[2Jx") == "s3://bucket/\\x1b[2Jx"


def test_a_reply_cut_short_is_a_storage_fault_named_as_such():
    aiohttp = pytest.importorskip("aiohttp")
    exc = aiohttp.ClientPayloadError("Response payload is not completed")
    assert is_storage_fault(exc)
    assert describe_storage_fault(exc) == "the object store's reply was cut short (fewer bytes than it announced)"


def _info_against(handle, name: str, monkeypatch, capsys) -> float:
    """`catalog info s3://dyana-test/NAME` against an endpoint on 127.0.0.1 whose every
    connection ``handle(connection, stop)`` serves; asserts one line naming the URL, exit 2;
    the seconds it took."""
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(16)
    stop = threading.Event()

    def accept() -> None:
        listener.settimeout(0.2)
        while not stop.is_set():
            try:
                threading.Thread(target=handle, args=(listener.accept()[0], stop), daemon=True).start()
            except OSError:
                continue

    threading.Thread(target=accept, daemon=True).start()
    monkeypatch.setenv("AWS_ENDPOINT_URL", f"http://127.0.0.1:{listener.getsockname()[1]}")
    monkeypatch.setenv("AWS_ACCESS_KEY_ID", "dyana-test")
    monkeypatch.setenv("AWS_SECRET_ACCESS_KEY", "dyana-test-secret")
    try:
        start = time.monotonic()
        code = catalog_main(["info", f"s3://dyana-test/{name}"])
        elapsed = time.monotonic() - start
    finally:
        stop.set()
        listener.close()
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and f"s3://dyana-test/{name}" in err, err
    return elapsed


def _silent(connection: socket.socket, stop: threading.Event) -> None:
    """Accept and never answer."""
    with connection:
        stop.wait(60)


def _trickle(connection: socket.socket, stop: threading.Event) -> None:
    """Answer a byte every 0.2 s, for ever."""
    with connection:
        connection.recv(65536)  # the request
        connection.sendall(b"HTTP/1.1 200 OK\r\nContent-Length: 1000000\r\nContent-Type: application/xml\r\n\r\n")
        while not stop.wait(0.2):
            try:
                connection.sendall(b" ")
            except OSError:
                return


@pytest.mark.slow(cover="tests/pipeline/test_storage_hostile.py::test_an_endpoint_that_trickles_its_reply_is_cut_by_the_request_deadline")
def test_an_endpoint_that_accepts_and_never_answers_times_out(no_aws, monkeypatch, capsys):  # noqa: F811
    monkeypatch.setattr(catalog.store.storage, "CLIENT_TIMEOUTS", {"connect_timeout": 1, "read_timeout": 1})
    assert _info_against(_silent, "silent", monkeypatch, capsys) < 30


@pytest.mark.parametrize("scheduler", ["tcp://127.0.0.1:{port}", "bogus://127.0.0.1:{port}"])
def test_an_unreachable_scheduler_leaves_no_folder_behind(tmp_path, capsys, monkeypatch, scheduler):
    """Before: the refused run left OUT/<slice>/.lock."""
    import pipeline.jobs.tasks
    from pipeline.cli import main

    monkeypatch.setattr(pipeline.jobs.tasks, "CONNECT_TIMEOUT_S", 0.5)  # not Dask's 30 s of retries
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]  # nothing listens there once the block ends
    code = main(["build", "--slice", "linear-fast", "--episodes", "1", "--out", str(tmp_path / "out"),
                 "--scheduler", scheduler.format(port=port), "--quiet"])
    err = capsys.readouterr().err
    assert code != 0 and err.count("\n") == 1 and "Traceback" not in err, err
    assert not (tmp_path / "out" / "linear-fast").exists()


def test_an_endpoint_that_trickles_its_reply_is_cut_by_the_request_deadline(no_aws, monkeypatch, capsys):  # noqa: F811
    """Before: a reply of a byte a second passed every per-read timeout and never ended.
    One attempt: s3fs retries a timed-out request 5 times (6 s of an idle test), which tests
    nothing more than the first attempt's deadline."""
    import s3fs

    monkeypatch.setattr(catalog.store.s3_session, "REQUEST_TOTAL_S", 1.0)
    monkeypatch.setattr(s3fs.S3FileSystem, "retries", 1)
    assert _info_against(_trickle, "trickle", monkeypatch, capsys) < 60
