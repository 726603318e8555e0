"""Sealed held-out runs: a ``module:callable`` policy evaluated on a private split runs in
namespaces of its own (:mod:`pipeline.remote.sandbox`), so a policy that hunts for the
secret finds nothing and scores at chance; where nothing seals it (a policy served on the
same machine), the same hunter finds the secret and wins."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from pipeline.jobs.evaluate import evaluate
from pipeline.remote import sandbox
from schemas.errors import SpecError
from scoring.io import load_run
from scoring.report import score_run
from tests.pipeline.test_remote import start_server

BIN = Path(sys.executable).parent
HUNTER = "tests.pipeline.hunter_policy:HunterPolicy"
EPISODES = 2
RESOLUTION = 32
#: The secret the hunter knows the sha256 of (tests.pipeline.hunter_policy.TARGET).
SECRET = "5b0e1c9d27f84a6e93c1d0b8f2a47e65"


def _scores(run: Path) -> dict[str, float]:
    metrics = score_run(load_run(run)).overall.metrics
    return {name: metrics[name] for name in ("S_loc", "E_loc", "S_gra", "S_grasp_contact")}


def _secret_file(tmp_path: Path) -> Path:
    path = tmp_path / "keep" / "test-seed.txt"
    path.parent.mkdir()
    path.write_text(SECRET + "\n")
    (tmp_path / "test-seed.bak").write_text(SECRET + "\n")  # a careless copy beside it, under /tmp
    return path


def _stat(proc: Path) -> tuple[int, int]:
    """The parent pid and the start time in ``proc``'s stat (after the command name, which may
    hold spaces), or (0, 0)."""
    try:
        fields = (proc / "stat").read_text().rsplit(")", 1)[1].split()
        return int(fields[1]), int(fields[19])
    except (OSError, IndexError, ValueError):
        return 0, 0


def _descends_from_us(proc: Path, known: dict[tuple[int, int], bool]) -> bool:
    """Whether ``proc`` is a descendant of this test process (the run's workers and policy
    processes are; another test's, in the other xdist worker, are not). ``known`` keeps the
    answer per process (pid and start time: a reused pid is another process), so each scan
    reads one stat file per process rather than its every ancestor's."""
    me, chain, answer = os.getpid(), [], False
    pid = int(proc.name)
    for _ in range(64):
        parent, start = _stat(Path("/proc") / str(pid))
        if (pid, start) in known:
            answer = known[(pid, start)]
            break
        chain.append((pid, start))
        if parent == me:
            answer = True
            break
        if parent <= 1:
            break
        pid = parent
    for key in chain:
        if key[1]:  # a process that was gone when read is asked about again next time
            known[key] = answer
    return answer


def _holders(stop: threading.Event, seen: list[str]) -> None:
    """Every process of this run (a descendant of this test process) whose command line or
    environment holds the secret, while the run lasts."""
    needle, known = SECRET.encode(), {}
    while not stop.is_set():
        for proc in Path("/proc").glob("[0-9]*"):
            if not _descends_from_us(proc, known):
                continue
            for name in ("cmdline", "environ"):
                try:
                    if needle in (proc / name).read_bytes():
                        seen.append(f"{proc}/{name}")
                except OSError:
                    pass
        stop.wait(0.05)


#: Where the machine cannot seal (no unshare, user namespaces off), the refusal test covers it.
needs_unshare = pytest.mark.skipif(sandbox.unavailable() is not None,
                                   reason=f"cannot seal a policy here: {sandbox.unavailable()}")


@needs_unshare
def test_a_hunter_finds_nothing_on_a_sealed_run_and_scores_like_a_still_hand(tmp_path):
    secret_file = _secret_file(tmp_path)
    common = dict(episodes=EPISODES, workers=0, resolution=RESOLUTION, progress=False, summary=False)
    stop, seen = threading.Event(), []
    watch = threading.Thread(target=_holders, args=(stop, seen), daemon=True)
    watch.start()
    try:
        manifest = evaluate(HUNTER, "test-1k", tmp_path / "sealed", test_seed=SECRET, test_seed_file=str(secret_file),
                            **common)
    finally:
        stop.set()
        watch.join()
    assert manifest.extra["policy"] == "hunter-blind"  # made in the driver's check and in the worker: both blind
    assert seen == []
    evaluate("still", "test-1k", tmp_path / "still", test_seed=SECRET, **common)
    sealed, still = _scores(tmp_path / "sealed"), _scores(tmp_path / "still")
    assert sealed == still and sealed["S_loc"] <= 5.0  # chance: a hand held still


def test_the_hunter_wins_where_nothing_seals_it(tmp_path):
    """The threat model's other side: a policy served on the eval's machine, outside any
    sandbox, reads the eval's command line and the secret file, and plays the ground truth."""
    secret_file = _secret_file(tmp_path)
    server, url = start_server(HUNTER)
    try:
        done = subprocess.run(
            [str(BIN / "pipeline"), "eval", "--policy", url, "--slice", "test-1k", "--episodes", str(EPISODES),
             "--resolution", str(RESOLUTION), "--out", str(tmp_path / "open"), "--test-seed-file", str(secret_file),
             "--quiet"], capture_output=True, text=True, timeout=300,
        )
    finally:
        server.kill()
        server.wait()
    assert done.returncode == 0, done.stderr
    assert "hunter-found" in done.stdout
    scores = _scores(tmp_path / "open")
    assert scores["S_loc"] == scores["S_grasp_contact"] == 100.0


def test_a_sealed_run_is_refused_in_one_line_where_unshare_is_missing(tmp_path, monkeypatch):
    monkeypatch.setenv("PATH", str(tmp_path))  # no unshare on it
    with pytest.raises(SpecError, match="util-linux unshare is not on PATH") as caught:
        evaluate(HUNTER, "test-1k", tmp_path / "run", episodes=1, workers=0, test_seed=SECRET, progress=False)
    assert "\n" not in str(caught.value) and SECRET not in str(caught.value)
    assert not (tmp_path / "run").exists()
    env = {**os.environ, "PATH": str(tmp_path)}
    done = subprocess.run([sys.executable, "-m", "pipeline.cli", "eval", "--policy", HUNTER, "--slice", "test-1k",
                           "--episodes", "1", "--out", str(tmp_path / "run"), "--test-seed", SECRET],
                          capture_output=True, text=True, env=env)
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert "sealed" in done.stderr and SECRET not in done.stderr


def test_a_sealed_run_is_refused_where_user_namespaces_are_off(tmp_path, monkeypatch):
    fake = tmp_path / "unshare"  # as util-linux answers where unprivileged user namespaces are disabled
    fake.write_text("#!/bin/sh\necho 'unshare: unshare failed: Operation not permitted' >&2\nexit 1\n")
    fake.chmod(0o755)
    monkeypatch.setenv("PATH", f"{tmp_path}:{os.environ['PATH']}")
    with pytest.raises(SpecError, match="this machine cannot: unshare: unshare failed: Operation not permitted"):
        evaluate(HUNTER, "test-1k", tmp_path / "run", episodes=1, workers=0, test_seed=SECRET, progress=False)
    assert not (tmp_path / "run").exists()


def test_a_private_seed_refuses_an_in_process_user_policy(tmp_path):
    with pytest.raises(SpecError, match="in-process"):
        evaluate(HUNTER, "test-1k", tmp_path / "run", episodes=1, workers=0, test_seed=SECRET, isolate=False,
                 progress=False)


def test_public_runs_and_policies_that_run_no_user_code_are_not_sealed():
    from pipeline.policy_registry import kind_named

    assert sandbox.sealing((), None, True, None, "/x") is None  # a public run of a module policy
    for name in ("builtin", "remote", "openpi", "vlm", "lerobot"):  # no user's code runs in Dyana's processes
        assert kind_named(name).sealed_files is None, name
    assert kind_named("module").sealed_files("mine:make") == ()
    assert kind_named("sb3").sealed_files("sb3:PPO:models/m.zip") == (os.path.abspath("models/m.zip"),)


@needs_unshare
def test_the_sandbox_shows_no_other_process_no_secret_writes_only_scratch_and_cannot_be_undone(tmp_path):
    secret_file = _secret_file(tmp_path)
    seal = sandbox.seal_for(str(secret_file), str(tmp_path / "run"))
    probe = (
        "import os, subprocess, sys\n"
        "print(sorted(p for p in os.listdir('/proc') if p.isdigit()))\n"
        f"print(os.path.exists({str(secret_file)!r}) and open({str(secret_file)!r}).read())\n"
        f"print(os.path.exists({str(tmp_path)!r}))\n"
        "print(sorted(os.environ))\n"
        "print(subprocess.run(['umount', '/tmp'], capture_output=True).returncode != 0)\n"
        "print(os.getuid())\n"
        "def write(path):\n"
        "    try:\n"
        "        open(path, 'a').close()\n"
        "        return 'wrote'\n"
        "    except OSError as exc:\n"
        "        return exc.strerror\n"
        f"print(write({str(Path(__file__).parent / 'planted.py')!r}), write('/tmp/scratch'))\n"
    )
    command = sandbox.command(seal, "unused", 0)
    command = command[: command.index("--") + 1] + [sys.executable, "-c", probe]
    done = subprocess.run(command, env=sandbox.environment(), capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    pids, secret, tmp_seen, env, locked, uid, writes = done.stdout.splitlines()
    assert pids in ("['1']", "['1', '2']")  # itself (and umount's child, gone by then)
    assert secret in ("False", "")  # gone with /tmp, or /dev/null where a folder is bound back
    assert tmp_seen == "False"
    assert env == "['HOME', 'LANG', 'PATH', 'PYTHONPATH']"
    assert locked == "True" and uid != "0"
    assert writes == "Read-only file system wrote"  # no planting code a worker or the driver imports later
    assert not (Path(__file__).parent / "planted.py").exists()


def test_the_secret_can_come_from_stdin_and_then_no_command_line_names_a_file(tmp_path, monkeypatch, capsys):
    import io

    from pipeline.cli import main

    run = tmp_path / "run"
    evaluate("still", "test-1k", run, episodes=1, workers=0, resolution=RESOLUTION, progress=False, summary=False,
             test_seed=SECRET)
    piped = subprocess.run([str(BIN / "pipeline"), "replay", str(run), "--test-seed-file", "-", "--quiet"],
                           input=SECRET + "\n", capture_output=True, text=True)
    assert piped.returncode == 0, piped.stderr
    # a wrong secret on stdin, through the CLI's main in this process (the piped one above is a real process's)
    monkeypatch.setattr("sys.stdin", io.TextIOWrapper(io.BytesIO(b"c3a9f1e07d2b4c68a5e19f30b7d64c28\n")))
    capsys.readouterr()
    assert main(["replay", str(run), "--test-seed-file", "-"]) == 2
    assert "does not match" in capsys.readouterr().err
    assert sandbox.seal_for("-", str(run)).files == ()  # nothing to cover: the policy never gets stdin


def test_a_sealed_configuration_costs_its_caller_no_more_than_the_cap():
    """What a sealed process prints back is the policy's word: kept to the cap however much it
    prints, and a process that never ends is killed at the deadline."""
    loud = subprocess.Popen([sys.executable, "-c", "import sys\nfor _ in range(2000): sys.stdout.write('x' * 65536)\n"
                                                   "sys.stderr.write('e' * 300000)"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    out, err = sandbox.capped_output(loud, 60, 1000)
    assert (len(out), len(err), loud.returncode) == (1001, 1001, 0)
    stuck = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE)
    with pytest.raises(subprocess.TimeoutExpired):
        sandbox.capped_output(stuck, 0.5, 1000)
    assert stuck.returncode is not None
