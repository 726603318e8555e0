"""A LeRobot ACT trained on Dyana with LeRobot's own `lerobot-train`, scored in Dyana's loop.

The journey of issue 28 with zero glue, as the docs give it (guides/export-lerobot.md):

1. ``pipeline build`` of the first ``--episodes-per-slice`` episodes of each of the nine
   atomic slices (the episodes chunk_cnn trains on) at ``--resolution`` into
   ``--work/train9``, then ``catalog export train9/*-* --format lerobot`` (v3.0).
2. ``VENV/bin/lerobot-train`` (``--venv``: a LeRobot release's environment with Dyana in it,
   made by ``.ci/lerobot-venvs``), offline, on CPU with one thread, ACT with
   ``--steps`` at batch 8. ACT is made smaller than LeRobot's default for a CPU budget: model
   width 256 (feed-forward 1024) and 20-frame chunks, executed 10 frames at a time (the
   default 100-frame chunk is longer than an episode's acting horizon), learning rate 1e-4.
   Its CPU time (the process and its data-loading worker: ``getrusage`` of the children)
   goes to ``--work/act/dyana_training.json``, its log to ``--work/train.log``. A finished
   training there (the same command) is kept.
3. ``VENV/bin/pipeline eval --policy lerobot:OUT`` on the first ``--eval-episodes`` episodes
   of test-1k at the same resolution into ``--work/runs/act``.
4. ``--out/record.json``: versions, commands, the training budget, the losses it logged
   (every 50 steps) and the run's hash;
   ``benchmarks/closed_loop_results.py --add-run WORK/runs/act`` puts the run in
   the results table beside the other rows.

    python benchmarks/lerobot_act.py --venv ~/.cache/dyana/lerobot-venvs/lerobot-0.4.4 --work act
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import subprocess
import sys
import time
from pathlib import Path

import bench_setup  # noqa: F401  (first: fixes sys.path, see bench_setup)

from catalog.store.manifest import load_manifest  # noqa: E402
from schemas.slices import ATOMIC_SLICES  # noqa: E402

#: Steps between lerobot-train's log lines (``--log_freq``).
LOG_FREQ = 50
ACT_OPTIONS = (
    "--policy.type=act", "--policy.device=cpu", "--policy.push_to_hub=false",
    "--policy.pretrained_backbone_weights=null",
    "--policy.chunk_size=20", "--policy.n_action_steps=10", "--policy.dim_model=256",
    "--policy.dim_feedforward=1024", "--policy.optimizer_lr=1e-4", "--policy.optimizer_lr_backbone=1e-4",
    "--batch_size=8", "--num_workers=1", f"--log_freq={LOG_FREQ}", "--wandb.enable=false", "--seed=1000",
)
#: The loss of a lerobot-train log line (``step:2K smpl:16K ... loss:0.272``; its step is rounded).
LOSS = re.compile(r"step:\S+ .*?loss:([\d.]+)")


def eval_record(run: Path, command: list[str], episodes: int) -> dict:
    """The evaluation's part of the record: its command, and from the run's catalog its hash,
    the commit that made it and its dataset version."""
    manifest = json.loads((run / "catalog.json").read_text())
    return {"command": command, "episodes": episodes, "hash": manifest["hash"], "commit": manifest["code"]["commit"],
            "dataset_version": manifest["settings"]["dataset_version"]}


def logged_losses(log: Path) -> list[tuple[int, float]]:
    """(step, loss) of every log line of a lerobot-train run: one line every LOG_FREQ steps."""
    return [(LOG_FREQ * (i + 1), float(loss)) for i, loss in enumerate(LOSS.findall(log.read_text()))]


def run(argv: list[str], **kwargs) -> None:
    print("$ " + " ".join(argv), file=sys.stderr, flush=True)
    subprocess.run(argv, check=True, **kwargs)


def train(venv: Path, dataset: Path, out: Path, steps: int) -> dict:
    """lerobot-train, or the record of the same finished training."""
    record_path = out / "dyana_training.json"
    command = [str(venv / "bin" / "lerobot-train"), "--dataset.repo_id=dyana/train9", f"--dataset.root={dataset}",
               *ACT_OPTIONS, f"--steps={steps}", f"--save_freq={steps}", f"--output_dir={out}"]
    if record_path.is_file():
        record = json.loads(record_path.read_text())
        if record["command"][1:] == command[1:]:
            return record
        raise SystemExit(f"{out} holds another training ({record_path}); use another --work")
    load_start = os.getloadavg()
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    log = out.parent / "train.log"
    env = {**os.environ, "OMP_NUM_THREADS": "1", "HF_HUB_OFFLINE": "1"}
    with log.open("w") as sink:
        run(command, env=env, stdout=sink, stderr=subprocess.STDOUT)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    record = {
        "load_average_start": [round(x, 2) for x in load_start],
        "load_average_end": [round(x, 2) for x in os.getloadavg()],
        "command": command,
        "steps": steps,
        "batch_size": 8,
        "cpu_seconds": round(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime, 1),
        "wall_seconds": round(time.perf_counter() - start, 1),
        "threads": 1,
    }
    record_path.write_text(json.dumps(record, indent=1) + "\n")
    return record


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--venv", required=True, help="a LeRobot release's venv with Dyana (.ci/lerobot-venvs)")
    parser.add_argument("--work", required=True, help="folder for the data, the training and the run (kept)")
    parser.add_argument("--episodes-per-slice", type=int, default=40)
    parser.add_argument("--resolution", type=int, default=96)
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--eval-episodes", type=int, default=450)
    parser.add_argument("--out", default=os.path.join(bench_setup.HERE, "results", "lerobot_act"))
    args = parser.parse_args(argv)
    venv, work = Path(args.venv).resolve(), Path(args.work).resolve()
    work.mkdir(parents=True, exist_ok=True)
    here = Path(sys.executable).parent
    for name in ATOMIC_SLICES:
        run([str(here / "pipeline"), "build", "--slice", name, "--episodes", str(args.episodes_per_slice),
             "--shard-size", str(args.episodes_per_slice), "--resolution", str(args.resolution), "--workers", "1",
             "--out", str(work / "train9"), "--quiet"])
    dataset = work / "lerobot-train9"
    run([str(here / "catalog"), "export", *(str(work / "train9" / n) for n in sorted(ATOMIC_SLICES)),
         "--format", "lerobot", "--out", str(dataset), "--quiet"])
    training = train(venv, dataset, work / "act", args.steps)
    runs = work / "runs" / "act"
    evaluate = [str(venv / "bin" / "pipeline"), "eval", "--policy", f"lerobot:{work / 'act'}", "--slice", "test-1k",
                "--episodes", str(args.eval_episodes), "--resolution", str(args.resolution), "--workers", "2",
                "--out", str(runs)]
    run(evaluate)
    probe = "import json, lerobot, torch; print(json.dumps({'lerobot': lerobot.__version__, 'torch': torch.__version__}))"
    versions = subprocess.run([str(venv / "bin" / "python"), "-c", probe], check=True, capture_output=True,
                              text=True).stdout
    record = {
        "versions": json.loads(versions),
        "data": {"slices": sorted(ATOMIC_SLICES), "episodes_per_slice": args.episodes_per_slice,
                 "resolution": args.resolution,
                 "frames": sum(load_manifest(work / "train9" / n).frames for n in ATOMIC_SLICES)},
        "training": training | {"logged_losses": logged_losses(work / "train.log")},
        "eval": eval_record(runs, evaluate[1:], args.eval_episodes),
    }
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "record.json").write_text(json.dumps(record, indent=1) + "\n")
    print(json.dumps(record))
    return 0


if __name__ == "__main__":
    sys.exit(main())
