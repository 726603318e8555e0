"""Opening a named file only when it is a regular file (specs files, catalog.json)."""

from __future__ import annotations

import os

from schemas.regular_files import file_kind, open_regular


def test_a_regular_file_opens_and_anything_else_is_named_without_blocking(tmp_path):
    regular = tmp_path / "specs.jsonl"
    regular.write_bytes(b"{}\n")
    handle, status = open_regular(regular)
    assert handle is not None and file_kind(status.st_mode) == "a regular file"
    with handle:
        assert handle.read() == b"{}\n"
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)  # no writer: a blocking open would wait for ever
    for path, kind in ((fifo, "a FIFO"), (tmp_path, "a folder"), ("/dev/zero", "a character device")):
        handle, status = open_regular(path)
        assert handle is None and file_kind(status.st_mode) == kind
