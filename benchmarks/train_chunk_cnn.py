"""Train the learned baseline ``chunk_cnn`` on Dyana data and score it in Dyana's loop.

1. Builds the first ``--episodes-per-slice`` episodes of each of the nine atomic slices
   (never test-1k) at ``--resolution`` into ``--data`` (kept; a built slice is reused).
2. Trains :class:`pipeline.policies.chunk_cnn.ChunkCNNPolicy` on their acting frames
   through ``catalog.open(..., keys="lerobot")`` (``pipeline.policies.chunk_cnn_training``)
   and writes the checkpoint and its training record to ``--out``
   (default ``benchmarks/results/chunk_cnn``: what ``chunk_cnn:pretrained`` loads).
3. Evaluates it closed loop on the first ``--eval-episodes`` test-1k episodes
   (``pipeline eval --policy pipeline.policies.chunk_cnn:pretrained``) and scores the run.

Prints progress, then the scores; the last line is one JSON object with the training
record and the metrics.

    python benchmarks/train_chunk_cnn.py                      # the README's row
    python benchmarks/train_chunk_cnn.py --episodes-per-slice 2 --epochs 1 --eval-episodes 9   # a quick check
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import bench_setup  # noqa: F401  (first: fixes sys.path)

from pipeline.cli import main as pipeline_main  # noqa: E402
from schemas.slices import ATOMIC_SLICES  # noqa: E402
from scoring.io import load_run  # noqa: E402
from scoring.report import report_dict, score_run  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes-per-slice", type=int, default=40)
    parser.add_argument("--resolution", type=int, default=224)
    parser.add_argument("--epochs", type=int, default=6)
    parser.add_argument("--batch-size", type=int, default=64)
    parser.add_argument("--lr", type=float, default=1e-3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--data", default=os.path.join(bench_setup.HERE, "..", ".train-data"))
    parser.add_argument("--out", default=os.path.join(bench_setup.HERE, "results", "chunk_cnn"))
    parser.add_argument("--eval-episodes", type=int, default=450)
    parser.add_argument("--run", default=None, help="evaluation folder (default: <out>/../runs/chunk_cnn)")
    args = parser.parse_args(argv)

    import torch

    from pipeline.policies.chunk_cnn import ChunkCNNConfig
    from pipeline.policies.chunk_cnn_training import train

    data = Path(args.data).resolve()
    common = ["--episodes", str(args.episodes_per_slice), "--resolution", str(args.resolution),
              "--workers", str(args.workers), "--quiet"]
    start = time.perf_counter()
    for name in ATOMIC_SLICES:
        if not (data / name / "catalog.json").is_file():
            code = pipeline_main(["build", "--slice", name, "--out", str(data), *common])
            if code != 0:
                return code
    build_seconds = time.perf_counter() - start
    print(f"training data: {len(ATOMIC_SLICES)} slices x {args.episodes_per_slice} episodes in {data} "
          f"({build_seconds:.0f} s)", file=sys.stderr)
    torch.set_num_threads(max(1, args.workers))
    policy, record = train(
        [str(data / name) for name in ATOMIC_SLICES], ChunkCNNConfig(), epochs=args.epochs,
        batch_size=args.batch_size, lr=args.lr, seed=args.seed, workers=args.workers,
        progress=lambda line: print(line, file=sys.stderr, flush=True),
    )
    record.update({"episodes_per_slice": args.episodes_per_slice, "resolution": args.resolution,
                   "folders": [f"<data>/{name}" for name in ATOMIC_SLICES], "build_seconds": round(build_seconds, 1)})
    out = Path(args.out)
    policy.save(out, record)
    print(f"checkpoint -> {out} ({record['training_frames']} frames, {record['seconds']} s of training)", file=sys.stderr)

    run = Path(args.run) if args.run else out.parent / "runs" / "chunk_cnn"
    env = dict(os.environ, DYANA_CHUNK_CNN=str(out))
    os.environ.update(env)
    code = pipeline_main(["eval", "--policy", "pipeline.policies.chunk_cnn:pretrained", "--slice", "test-1k",
                          "--episodes", str(args.eval_episodes), "--workers", str(args.workers), "--out", str(run),
                          "--overwrite", "--quiet"])
    if code != 0:
        return code
    scores = report_dict(score_run(load_run(run)))
    print(json.dumps(scores["metrics"], indent=2))
    print(json.dumps({"benchmark": "train_chunk_cnn", "record": record, "metrics": scores["metrics"],
                      "by_motion": {k: {m: v[m] for m in ("S_loc", "S_gra", "S_grasp_contact")}
                                    for k, v in scores["by_motion"].items()}}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
