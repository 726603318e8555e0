"""catalog.store.outputs: a user-named output is renamed into place only over a regular file (or
nothing); a device or FIFO is written as such; a folder, socket or block device, and a
path inside a folder being read, are refused naming them."""

from __future__ import annotations

import os
import socket
import stat

import pytest

from catalog.store.outputs import check_output, open_output, place, staged_output
from schemas.errors import OutputError


def _char_device(path) -> None:
    """A character device node like /dev/null (1, 3) at ``path``; skip where mknod is not allowed."""
    try:
        os.mknod(path, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
    except (PermissionError, OSError) as exc:
        pytest.skip(f"cannot make a device node here: {exc}")


def test_a_regular_file_is_replaced_whole_and_a_symlink_kept(tmp_path):
    real, link = tmp_path / "real.csv", tmp_path / "link.csv"
    real.write_text("old")
    link.symlink_to(real)
    with open_output(link, "w") as handle:
        handle.write("new")
    assert link.is_symlink() and real.read_text() == "new"
    with pytest.raises(RuntimeError), open_output(real, "w") as handle:
        handle.write("half")
        raise RuntimeError("interrupted")
    assert real.read_text() == "new"  # a failed write leaves the old file, and no temp
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link.csv", "real.csv"]


def test_a_character_device_stays_a_device(tmp_path):
    device = tmp_path / "null"
    _char_device(device)
    with open_output(device, "w") as handle:
        handle.write("x" * 1000)
    assert stat.S_ISCHR(device.lstat().st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["null"]


def test_dev_null_stays_a_device():
    with open_output("/dev/null", "wb") as handle:
        handle.write(b"x")
    assert stat.S_ISCHR(os.lstat("/dev/null").st_mode)


def test_a_fifo_is_written_through_not_replaced(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    reader = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)
    try:
        with open_output(fifo, "w") as handle:
            handle.write("rows\n")
        assert os.read(reader, 100) == b"rows\n"
    finally:
        os.close(reader)
    assert stat.S_ISFIFO(fifo.lstat().st_mode)


def test_folders_sockets_and_links_to_them_are_refused(tmp_path):
    folder = tmp_path / "folder"
    folder.mkdir()
    link = tmp_path / "to-folder"
    link.symlink_to(folder)
    sock_path = tmp_path / "s.sock"
    server = socket.socket(socket.AF_UNIX)
    server.bind(str(sock_path))
    try:
        for path, what in ((folder, "a folder"), (link, "a folder"), (sock_path, "a socket")):
            with pytest.raises(OutputError, match=what) as caught:
                check_output(path, flag="--csv")
            assert "--csv" in str(caught.value) and str(path) in str(caught.value) and "\n" not in str(caught.value)
    finally:
        server.close()
    assert folder.is_dir() and stat.S_ISSOCK(sock_path.lstat().st_mode)


@pytest.mark.skipif(not os.path.exists("/dev/loop0") and not os.path.exists("/dev/sda"), reason="no block device")
def test_a_block_device_is_refused():
    device = "/dev/loop0" if os.path.exists("/dev/loop0") else "/dev/sda"
    with pytest.raises(OutputError, match="block device"):
        check_output(device)


def test_an_output_inside_an_input_folder_is_refused_naming_both(tmp_path):
    run = tmp_path / "run"
    (run / "frames").mkdir(parents=True)
    (run / "catalog.json").write_text("{}")
    alias = tmp_path / "alias"
    alias.symlink_to(run)
    for path in (run / "catalog.json", run / "stats.json", run / "frames" / "x.parquet", alias / "out.md"):
        with pytest.raises(OutputError) as caught:
            check_output(path, [run], flag="--markdown")
        message = str(caught.value)
        assert str(path) in message and str(run) in message and "being read" in message
    check_output(tmp_path / "run.md", [run])  # beside it is fine, even with the folder's name as prefix
    assert (run / "catalog.json").read_text() == "{}"


def test_an_empty_or_missing_device_path_is_refused():
    with pytest.raises(OutputError, match="--episodes: the path is empty"):
        check_output("", flag="--episodes")
    with pytest.raises(OutputError, match="no such device"):
        check_output("/dev/no-such-dyana-device")


def test_place_moves_a_finished_file_by_the_same_rule(tmp_path):
    temp = tmp_path / ".out.rrd.tmp-1"
    temp.write_bytes(b"recording")
    place(temp, tmp_path / "out.rrd")  # renamed: the temp is in the file's folder
    assert (tmp_path / "out.rrd").read_bytes() == b"recording" and not temp.exists()
    temp.write_bytes(b"recording")
    place(temp, "/dev/null")
    assert stat.S_ISCHR(os.lstat("/dev/null").st_mode) and not temp.exists()


def test_a_staged_output_lands_by_the_same_rule_and_never_stages_in_dev(tmp_path):
    with staged_output(tmp_path / "rec.rrd") as temp:
        assert temp.parent == tmp_path
        temp.write_bytes(b"rrd")
    assert (tmp_path / "rec.rrd").read_bytes() == b"rrd" and sorted(tmp_path.iterdir()) == [tmp_path / "rec.rrd"]
    with staged_output("/dev/null", flag="--out") as temp:
        assert not str(temp).startswith("/dev/")
        temp.write_bytes(b"rrd")
    assert not temp.exists() and stat.S_ISCHR(os.lstat("/dev/null").st_mode)
    with pytest.raises(RuntimeError), staged_output(tmp_path / "other.rrd") as temp:
        temp.write_bytes(b"half")
        raise RuntimeError("rerun failed")
    assert sorted(tmp_path.iterdir()) == [tmp_path / "rec.rrd"]
    with pytest.raises(OutputError, match="being read"), staged_output(tmp_path / "x.rrd", [tmp_path], "--out"):
        pass


def test_stdout_redirected_to_a_file_is_appended_to_and_dev_shm_is_a_folder_of_files(tmp_path):
    import subprocess
    import sys

    target = tmp_path / "log.txt"
    code = ("import sys; print('table', flush=True); from catalog.store.outputs import open_output\n"
            "with open_output('/dev/stdout') as h: h.write('csv\\n')")
    with open(target, "w") as out:
        subprocess.run([sys.executable, "-c", code], stdout=out, check=True)
    assert target.read_text() == "table\ncsv\n"
    if os.path.isdir("/dev/shm") and os.access("/dev/shm", os.W_OK):
        check_output(f"/dev/shm/dyana-test-{os.getpid()}.csv")  # a file system under /dev, not a device


@pytest.mark.parametrize("url", ["s3://bucket/out.csv", "gs://bucket/x/plot.png"])
def test_a_url_is_refused_and_makes_no_local_folder(tmp_path, monkeypatch, url):
    """Path("s3://b/k") is the local path "s3:/b/k": writing it would make a folder "s3:"."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(OutputError, match=r"--csv '.*': is a URL; this output is a local file"):
        check_output(url, [], "--csv")
    with pytest.raises(OutputError, match="is a URL"):
        with open_output(url, "w") as handle:
            handle.write("x")
    assert list(tmp_path.iterdir()) == []
