import os
import subprocess
import sys

import pytest

from catalog.store import atomic


def test_write_text_appears_complete(tmp_path):
    target = tmp_path / "sub" / "file.json"
    atomic.atomic_write_text(target, "hello\n")
    assert target.read_text() == "hello\n"
    assert atomic.find_stray_temps(tmp_path) == []


def test_failed_write_leaves_nothing_and_keeps_the_old_file(tmp_path):
    target = tmp_path / "file.bin"
    target.write_bytes(b"old")
    with pytest.raises(RuntimeError):
        with atomic.atomic_open(target) as handle:
            handle.write(b"half")
            assert atomic.temp_path(target).exists()
            raise RuntimeError("boom")
    assert target.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file.bin"]


def test_temp_name_is_hidden_beside_the_destination(tmp_path):
    temp = atomic.temp_path(tmp_path / "a.mcap", pid=42)
    assert temp == tmp_path / ".a.mcap.tmp-42"
    assert atomic.TEMP_PATTERN.match(temp.name)["name"] == "a.mcap"


def _dead_pid() -> int:
    done = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    return int(done.stdout)


def test_remove_stray_temps_only_of_dead_writers(tmp_path):
    (tmp_path / "shards").mkdir()
    dead = atomic.temp_path(tmp_path / "shards" / "x.mcap", pid=_dead_pid())
    mine = atomic.temp_path(tmp_path / "shards" / "y.mcap")
    dead.write_bytes(b"1")
    mine.write_bytes(b"2")
    (tmp_path / "shards" / "x.mcap").write_bytes(b"final")
    assert atomic.find_stray_temps(tmp_path) == sorted([dead, mine])
    assert atomic.remove_stray_temps(tmp_path) == [dead]
    assert mine.exists() and not dead.exists()
    assert atomic.remove_stray_temps(tmp_path, only_dead=False) == [mine]
    assert sorted(p.name for p in (tmp_path / "shards").iterdir()) == ["x.mcap"]


def test_commit_replaces_destination(tmp_path):
    final = tmp_path / "f"
    final.write_bytes(b"old")
    temp = atomic.temp_path(final)
    temp.write_bytes(b"new")
    atomic.commit(temp, final)
    assert final.read_bytes() == b"new" and not temp.exists()
    atomic.discard(temp)  # absent: no error
    assert os.listdir(tmp_path) == ["f"]
