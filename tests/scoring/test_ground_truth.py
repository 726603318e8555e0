"""The GT row: ground-truth episodes written as a built slice, and the same episodes
written as rollouts, score 100% on both success rates (integration with the generators)."""

from __future__ import annotations

import json

import pytest

from catalog.store.manifest import CodeInfo, Manifest, write_manifest
from catalog.tables.shard import ShardWriter
from scoring.cli import main

episode_module = pytest.importorskip("pipeline.stages.episode")
recipe = pytest.importorskip("generators.recipe")
from schemas.versions import DATASET_VERSION  # noqa: E402

SETTINGS = {"fps": 20, "resolution": 32, "image_format": "jpeg", "jpeg_quality": 90, "dataset_version": DATASET_VERSION}


def write_slice(folder, specs, policy=None):
    shards = []
    for first in range(0, len(specs), 4):
        chunk = specs[first:first + 4]
        with ShardWriter(folder, first, first + len(chunk), SETTINGS, rollout=policy is not None) as shard:
            for spec in chunk:
                frames = episode_module.episode(spec)
                images = [b"\xff\xd8\xff\xd9"] * frames.num_frames
                extra = {} if policy is None else {"policy": policy, "status": "ok"}
                shard.add_episode(spec, frames, images, **extra)
        shards.append(shard.record)
    extra = {} if policy is None else {"policy": policy}
    write_manifest(folder, Manifest.create(specs[0].slice, 1, SETTINGS, shards, code=CodeInfo("0.1.0", None), extra=extra))
    return folder


def test_ground_truth_slice_and_its_replay_as_rollouts_score_the_gt_row(tmp_path, capsys):
    specs = [recipe.spec_for("test-1k", i) for i in range(9)]
    gt = write_slice(tmp_path / "test-1k", specs)
    oracle = write_slice(tmp_path / "oracle-run", specs, policy="oracle")
    assert main(["eval", str(gt), str(oracle), "--json"]) == 0
    gt_row, oracle_row = json.loads(capsys.readouterr().out)
    assert gt_row["ground_truth"] and gt_row["label"] == "GT (test-1k)"
    assert gt_row["episodes"] == len(specs) and gt_row["errors"] == 0
    assert gt_row["metrics"]["S_loc"] == 100.0 and gt_row["metrics"]["S_gra"] == 100.0
    assert gt_row["metrics"]["E_loc"] < 0.3 and gt_row["metrics"]["R_time"] > 0.0
    assert gt_row["failures"]["success"] == len(specs) == oracle_row["failures"]["success"]
    same = {k: v for k, v in gt_row["metrics"].items() if k != "R_time"}
    assert {k: oracle_row["metrics"][k] for k in same} == same
    # Rollouts measure R_time against their acting horizon, 1.2x the ground truth's
    # acting frames, so the same trajectory scores 1 - (1 - R_gt) / 1.2, up to rounding.
    expected = 1 - (1 - gt_row["metrics"]["R_time"]) / 1.2
    assert oracle_row["metrics"]["R_time"] == pytest.approx(expected, abs=0.02)
