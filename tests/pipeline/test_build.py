"""`pipeline build` end to end: byte-identical across worker counts, an external Dask
scheduler and a killed-and-resumed build; user specs; bad input."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from catalog.store.manifest import load_manifest
from catalog.tables.integrity import verify_files
from pipeline.jobs.build import build
from pipeline.jobs.state import STATE_FILE
from schemas.errors import SpecError
from tests.shard_files import shard_bytes

SLICE = "linear-fast"
EPISODES = 6
SHARD = 2
RESOLUTION = 64
BIN = Path(sys.executable).parent


def _files(slice_dir: Path) -> dict[str, bytes]:
    return shard_bytes(slice_dir)


def _build(out: Path, **kwargs):
    return build(SLICE, out, episodes=EPISODES, resolution=RESOLUTION, shard_size=SHARD, progress=False, **kwargs)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """Built in this process (no Dask): the two-worker build below must give its bytes."""
    out = tmp_path_factory.mktemp("in-process")
    manifest = _build(out, workers=0)
    return manifest, out / SLICE


def test_build_writes_a_verifiable_catalog(reference):
    manifest, slice_dir = reference
    assert manifest.episodes == EPISODES
    assert len(manifest.shards) == EPISODES // SHARD
    assert load_manifest(slice_dir).hash == manifest.hash
    verify_files(slice_dir)
    assert not (slice_dir / STATE_FILE).exists()
    assert sorted(p.name for p in slice_dir.iterdir()) == [".lock", "catalog.json", "episodes", "frames", "mcap", "stats.json"]


def test_two_workers_give_the_same_bytes(reference, tmp_path):
    manifest, slice_dir = reference
    other = _build(tmp_path, workers=2)
    assert other.hash == manifest.hash
    assert _files(tmp_path / SLICE) == _files(slice_dir)
    for name in ("catalog.json", "stats.json"):
        assert (tmp_path / SLICE / name).read_bytes() == (slice_dir / name).read_bytes()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow(cover="tests/pipeline/test_build.py::test_two_workers_give_the_same_bytes")
def test_external_scheduler_gives_the_same_hash(reference, tmp_path):
    """A scheduler and a worker started by hand (30 s). .ci/run's multi-host tests build on
    an external scheduler with workers on other hosts and compare the local hash."""
    manifest, _ = reference
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    scheduler = subprocess.Popen(
        [str(BIN / "dask"), "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env,
    )
    worker = subprocess.Popen(
        [str(BIN / "dask"), "worker", address, "--nthreads", "1", "--nworkers", "2", "--no-dashboard",
         "--host", "127.0.0.1"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env,
    )
    try:
        from dask.distributed import Client

        with Client(address, timeout="30s") as client:
            client.wait_for_workers(2, timeout=60)
        other = _build(tmp_path, scheduler=address)
    finally:
        for proc in (worker, scheduler):
            proc.terminate()
        for proc in (worker, scheduler):
            proc.wait(timeout=30)
    assert other.hash == manifest.hash


@pytest.mark.slow(cover="tests/pipeline/test_object_store.py::test_a_killed_remote_build_resumes_on_another_machine")
def test_killed_build_resumes_to_the_same_bytes(reference, tmp_path):
    """SIGKILL of a local build mid-run, then the same command (20 s). The default run
    resumes a killed build through the same engine in tests/pipeline/test_object_store.py
    (killed mid-shard, resumed on another machine) and an interrupted one in
    tests/pipeline/test_runner.py (kept shards counted as done)."""
    manifest, slice_dir = reference
    cmd = [str(BIN / "pipeline"), "build", "--slice", SLICE, "--episodes", str(EPISODES), "--shard-size", "1",
           "--resolution", str(RESOLUTION), "--workers", "1", "--out", str(tmp_path)]
    # shard-size 1 gives a different layout; the reference for it is built uninterrupted below.
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    state = tmp_path / SLICE / STATE_FILE
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        if state.exists() and len(json.loads(state.read_text())["shards"]) >= 2:
            break
        time.sleep(0.05)
    else:
        proc.kill()
        pytest.fail("the build recorded no shard in time")
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not (tmp_path / SLICE / "catalog.json").exists()

    resumed = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    assert "resuming: " in resumed.stderr

    fresh_out = tmp_path / "fresh"
    fresh = build(SLICE, fresh_out, episodes=EPISODES, resolution=RESOLUTION, shard_size=1, workers=1, progress=False)
    assert load_manifest(tmp_path / SLICE).hash == fresh.hash
    assert _files(tmp_path / SLICE) == _files(fresh_out / SLICE)
    leftovers = [p.name for p in (tmp_path / SLICE).rglob("*") if p.name.startswith(".")]
    assert leftovers == [".lock"]  # no temporary or state; the lock file stays


def test_specs_file_builds_the_same_episodes(reference, tmp_path):
    manifest, slice_dir = reference
    specs = subprocess.run(
        [str(BIN / "catalog"), "specs", SLICE, "--episodes", str(EPISODES)], capture_output=True, text=True, check=True
    ).stdout
    path = tmp_path / "specs.jsonl"
    path.write_text(specs)
    other = build(None, tmp_path / "out", specs_path=str(path), resolution=RESOLUTION, shard_size=SHARD,
                  workers=0, progress=False)
    assert other.hash == manifest.hash


@pytest.mark.parametrize(
    "args, needle",
    [
        (["--slice", "linear-warp"], "linear-warp"),
        (["--slice", "linear-fast", "--episodes", "0"], "--episodes"),
        (["--slice", "linear-fast", "--episodes", "999999"], "999999"),
        (["--slice", "linear-fast", "--resolution", "3"], "resolution"),
    ],
)
def test_bad_input_exits_2_with_one_line(tmp_path, args, needle):
    result = subprocess.run(
        [str(BIN / "pipeline"), "build", "--out", str(tmp_path), *args], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 2
    assert needle in result.stderr
    assert "Traceback" not in result.stderr


def test_bad_specs_file_names_the_line(tmp_path):
    path = tmp_path / "bad.jsonl"
    path.write_text('{"slice": "x"}\n')
    result = subprocess.run(
        [str(BIN / "pipeline"), "build", "--specs", str(path), "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=120,
    )
    assert result.returncode == 2
    assert f"{path}:1" in result.stderr
    assert not (tmp_path / "x").exists()


def test_an_edited_specs_file_is_refused_then_replaced_only_with_overwrite(tmp_path):
    """A folder built from one specs file is not silently rebuilt from another: the
    refusal names the specs hash that differs; with overwrite the new episodes replace it."""
    import dataclasses

    from generators.recipe import spec_for

    specs = [spec_for(SLICE, i) for i in range(2)]
    path = tmp_path / "specs.jsonl"
    path.write_text("".join(s.to_json() + "\n" for s in specs))
    out = tmp_path / "out"
    first = build(None, out, specs_path=str(path), resolution=RESOLUTION, shard_size=1, workers=0, progress=False)
    edited = [specs[0], dataclasses.replace(specs[1], text="Grasp it, please.")]
    path.write_text("".join(s.to_json() + "\n" for s in edited))
    with pytest.raises(SpecError, match="another job.*specs_sha256"):
        build(None, out, specs_path=str(path), resolution=RESOLUTION, shard_size=1, workers=0, progress=False)
    assert load_manifest(out / SLICE).hash == first.hash
    second = build(None, out, specs_path=str(path), resolution=RESOLUTION, shard_size=1, workers=0, progress=False,
                   overwrite=True)
    texts = [t for shard in second.shards
             for t in pq.read_table(out / SLICE / shard.files["episodes"].path).column("text").to_pylist()]
    assert texts == [specs[0].text, "Grasp it, please."]


def test_rebuilding_with_another_shard_size_leaves_no_stale_shards(reference, tmp_path):
    """Another --shard-size is refused; replaced on purpose (overwrite), the folder holds
    only the new shards: the old ones would fail `catalog verify` and be read by globs."""
    import shutil

    _, slice_dir = reference
    shutil.copytree(slice_dir, tmp_path / SLICE)
    with pytest.raises(SpecError, match="another job"):
        build(SLICE, tmp_path, episodes=EPISODES, resolution=RESOLUTION, shard_size=3, workers=0, progress=False)
    manifest = build(SLICE, tmp_path, episodes=EPISODES, resolution=RESOLUTION, shard_size=3, workers=0, progress=False,
                     overwrite=True)
    listed = sorted(f.path for s in manifest.shards for f in s.files.values())
    assert sorted(_files(tmp_path / SLICE)) == listed
    verify_files(tmp_path / SLICE)


@pytest.mark.parametrize("address", ["not-an-address::", "tcp://127.0.0.1:notaport", "nope", "tcp://h:99999", ""])
def test_a_malformed_scheduler_address_is_one_line_and_exit_2_before_the_folder_is_made(tmp_path, address, capsys):
    """Through the command's entry point in this process (what the console script calls; a
    process each cost its start: the bad-input tests above run the command as a process)."""
    from pipeline.cli import main

    code = main(["build", "--slice", SLICE, "--episodes", "1", "--out", str(tmp_path / "out"), "--scheduler", address])
    err = capsys.readouterr().err
    assert code == 2, err
    assert f"--scheduler {address!r}: not a Dask scheduler address" in err and "Traceback" not in err
    assert err.count("\n") == 1, err
    assert not (tmp_path / "out").exists()  # no folder, no lock left behind


def test_an_unreachable_scheduler_is_one_line_and_exit_2(tmp_path):
    """The command in a process of its own, waiting 0.5 s for the scheduler instead of 30
    (a refused connection is retried until the timeout: 30 s of an idle test process)."""
    command = ("import sys; import pipeline.jobs.tasks as t; t.CONNECT_TIMEOUT_S = 0.5; "
               "from pipeline.cli import main; sys.exit(main())")
    result = subprocess.run(
        [sys.executable, "-c", command, "build", "--slice", SLICE, "--episodes", "1", "--out", str(tmp_path),
         "--scheduler", "tcp://127.0.0.1:1"],
        capture_output=True, text=True, timeout=120,
    )
    assert result.returncode == 2, result.stderr
    assert "--scheduler 'tcp://127.0.0.1:1': cannot connect" in result.stderr and "Traceback" not in result.stderr


def test_a_build_starts_without_the_closed_loop():
    """`pipeline build` runs no policy: its modules import neither the rollout nor gymnasium
    (about 0.1 CPU s a process, in every build and every Dask worker)."""
    code = ("import sys; import pipeline.cli, pipeline.jobs.build, pipeline.stages.record; "
            "print(sorted(m for m in ('gymnasium', 'pipeline.loop.rollout', 'pipeline.loop.env') if m in sys.modules))")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]", result.stdout


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / "pipeline"), *args], capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("name", ["../../victim/linear-slow", "/abs/path", "a/b", ".", "..", "x\u0000y"])
def test_a_spec_slice_name_is_never_a_path(reference, tmp_path, name, capsys):
    """A spec's slice name cannot point the build at (and delete) another folder. Through
    the command's entry point in this process (a process each cost its start)."""
    import json as _json
    import shutil

    from generators.recipe import spec_for
    from pipeline.cli import main

    _, slice_dir = reference
    victim = tmp_path / "victim" / "linear-slow"
    shutil.copytree(slice_dir, victim)
    before = _files(victim)
    spec = _json.loads(spec_for(SLICE, 0).to_json())
    spec["slice"] = name
    path = tmp_path / "work" / "specs.jsonl"
    path.parent.mkdir()
    path.write_text(_json.dumps(spec) + "\n")
    code = main(["build", "--specs", str(path), "--out", str(tmp_path / "work" / "out"), "--resolution", "32"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert f"{path}:1" in err and "never a path" in err and "Traceback" not in err
    assert _files(victim) == before and not (tmp_path / "work" / "out").exists()


def test_custom_specs_never_replace_a_recipe_build_unasked_and_a_rebuild_is_up_to_date(reference, tmp_path, capsys):
    """The commands run in this process (``pipeline.cli.main``, which the console script
    calls): a process each cost its start for nothing this checks; the tests above run the
    command in processes of its own, and test_specs_file_builds_the_same_episodes builds
    from what ``catalog specs`` prints."""
    import shutil

    from generators.recipe import spec_for
    from pipeline.cli import main

    manifest, slice_dir = reference
    shutil.copytree(slice_dir, tmp_path / SLICE)
    common = ["--out", str(tmp_path), "--resolution", str(RESOLUTION), "--shard-size", str(SHARD), "--workers", "1"]
    code = main(["build", "--slice", SLICE, "--episodes", str(EPISODES), *common])
    again = capsys.readouterr()
    assert code == 0, again.err
    assert again.out.startswith(f"up to date {SLICE}: {EPISODES} episodes")
    specs = tmp_path / "mine.jsonl"
    specs.write_text("".join(spec_for(SLICE, i).to_json() + "\n" for i in range(2)))
    code = main(["build", "--specs", str(specs), *common])
    refused = capsys.readouterr()
    assert code == 2 and "holds another job" in refused.err and "specs_sha256" in refused.err
    assert "--overwrite" in refused.err and refused.err.count("\n") == 1 and "Traceback" not in refused.err
    assert load_manifest(tmp_path / SLICE).hash == manifest.hash and _files(tmp_path / SLICE) == _files(slice_dir)
    code = main(["build", "--specs", str(specs), "--overwrite", *common])
    assert code == 0, capsys.readouterr().err
    assert load_manifest(tmp_path / SLICE).episodes == 2


def _spec_lines(*changes: dict) -> str:
    import json as _json

    from generators.recipe import spec_for

    lines = []
    for i, change in enumerate(changes):
        spec = _json.loads(spec_for(SLICE, i).to_json())
        spec.update(change)
        lines.append(_json.dumps(spec))
    return "\n".join(lines) + "\n"


def test_a_duplicate_episode_index_is_named_as_a_duplicate(tmp_path):
    path = tmp_path / "dup.jsonl"
    path.write_text(_spec_lines({}, {"episode_index": 0}))
    result = _cli("build", "--specs", str(path), "--out", str(tmp_path / "out"))
    assert result.returncode == 2 and result.stderr.count("\n") == 1
    assert f"{path}:2: episode_index 0 is a duplicate (line 1 has it)" in result.stderr


def test_an_infeasible_spec_is_one_line_with_its_file_and_line_and_no_dask_noise(tmp_path):
    path = tmp_path / "far.jsonl"
    fast = {"motion": {"base": [{"type": "L", "start": [0.0, 3.0], "direction": 0.0, "speed": 40.0,
                                 "acceleration": 0.0, "duration": 4.0}]}}
    path.write_text(_spec_lines({}, fast))
    result = _cli("build", "--specs", str(path), "--out", str(tmp_path / "out"), "--workers", "2")
    assert result.returncode == 2, result.stderr
    assert result.stderr.count("\n") == 1 and f"{path}:2: infeasible episode" in result.stderr
    assert "Traceback" not in result.stderr and "Compute Failed" not in result.stderr


def test_a_line_after_a_flight_still_in_the_air_is_one_line_with_its_file_and_line(tmp_path):
    path = tmp_path / "flight.jsonl"
    flight = {"motion_type": "custom", "motion": {"base": [
        {"type": "P", "start": [0.0, 3.0], "velocity": [0.5, 3.0, 0.5], "height": 1.0, "duration": 0.1},
        {"type": "L", "start": [0.0, 0.0], "direction": 0.0, "speed": 1.0, "acceleration": 0.0, "duration": 4.0}]}}
    path.write_text(_spec_lines({}, flight))
    result = _cli("build", "--specs", str(path), "--out", str(tmp_path / "out"))
    assert result.returncode == 2, result.stderr
    assert result.stderr.count("\n") == 1 and f"{path}:2: episode " in result.stderr
    assert "in the air: a planar token after a projectile needs it back on the table" in result.stderr


def test_a_spec_whose_object_the_resting_hand_hides_is_refused_with_the_frame(tmp_path):
    """A tennis ball rolled toward the camera passes under the resting fingers while it
    is observed: refused before any work, naming the file, line and observe frame."""
    import math

    path = tmp_path / "hidden.jsonl"
    toward_camera = {
        "object": "tennis_ball", "object_size": 0.67, "observe_frames": 20, "num_frames": 40,
        "rollout_format": "observe-before-act", "intercept_setting": "fast",
        "motion": {"base": [{"type": "L", "start": [0.0, 2.0], "direction": -math.pi / 2, "speed": 2.5,
                             "acceleration": 0.0, "duration": 2.0}]},
    }
    path.write_text(_spec_lines({}, toward_camera))
    result = _cli("build", "--specs", str(path), "--out", str(tmp_path / "out"))
    assert result.returncode == 2, result.stderr
    assert result.stderr.count("\n") == 1, result.stderr
    assert f"{path}:2: infeasible episode" in result.stderr
    assert "% visible at observe frame 16 " in result.stderr
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").rglob("*.parquet"))


@pytest.mark.slow(cover="tests/pipeline/test_runner.py::test_a_dask_build_reports_episodes_before_its_shard_finishes_and_quiet_is_silent")
def test_a_dask_build_prints_only_dyana_lines_even_beside_another_dashboard(tmp_path):
    """No dashboard is bound to 8787 (so no 'Port 8787 is already in use' warning), and no
    Dask log line (heartbeats, comm closing) reaches the user. The default run checks both
    on a one-worker build in tests/pipeline/test_runner.py (8787 taken, every line a
    progress line, --quiet silent); this one repeats it with two worker processes (7 CPU s)."""
    with socket.socket() as taken:
        try:
            taken.bind(("127.0.0.1", 8787))
        except OSError:
            pass  # already taken by something else: the point holds either way
        result = _cli("build", "--slice", SLICE, "--episodes", "4", "--shard-size", "2", "--workers", "2",
                      "--resolution", "32", "--out", str(tmp_path))
    assert result.returncode == 0, result.stderr
    about, *lines = result.stderr.splitlines()
    assert about.startswith("building linear-fast: ") and "frames" in about, result.stderr  # how big, said first
    assert lines and all(line.startswith("[") for line in lines), result.stderr


def test_the_loader_gives_opencvs_pixels_of_the_rendered_frames(reference):
    """The dataloader decodes with simplejpeg (faster, and straight into a window's array);
    on real renders it gives exactly what ``cv2.imdecode`` gives, so items did not change."""
    import cv2
    import numpy as np

    import catalog

    manifest, root = reference
    ds = catalog.open(root)
    windows = catalog.open(root, history=1)
    images = []
    for shard in manifest.shards:
        images += pq.read_table(root / shard.files["frames"].path, columns=["image"]).column("image").to_pylist()
    assert len(images) == len(ds)
    for i, jpeg in enumerate(images):
        expected = cv2.cvtColor(cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
        np.testing.assert_array_equal(ds[i]["image"], expected)
        np.testing.assert_array_equal(windows[i]["image"][-1], expected)
