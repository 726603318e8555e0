"""S_hold: scoring runs the hold test (generators.hold) from each recorded episode's closing
frame, as :func:`generators.hold_episode.episode_hold` does on the whole episode."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from generators.grasp import OPPOSED, OPPOSED_WRIST, SPLAYED, design_of
from generators.ground_truth import plan
from generators.hold_episode import episode_hold
from generators.recipe import spec_for
from pipeline.stages.episode import episode
from schemas.errors import SpecError
from schemas.versions import DATASET_VERSION
from scoring.hold import run_metrics
from scoring.io import from_recordings
from scoring.metrics import DYANA, aggregate

#: test-1k's first episodes: a lying cylinder (the opposed grasp turns the palm for it) among them.
EPISODES = range(6)


def recorded(design):
    """Ground-truth recordings of test-1k's first episodes as ``design`` grasps."""
    specs = [spec_for("test-1k", k) for k in EPISODES]
    frames = []
    for spec in specs:
        gt = episode(spec)
        hand = plan(spec, design)[0]
        frames.append(dataclasses.replace(gt, palm_pose=hand.palm_pose.astype(np.float32),
                                          joint_angles=hand.joint_angles.astype(np.float32),
                                          grasp_angles=hand.grasp_angles.astype(np.float32)))
    return specs, frames


@pytest.mark.parametrize("design", [OPPOSED, SPLAYED], ids=lambda d: d.name)
def test_scoring_holds_what_the_hold_test_of_the_whole_episode_holds(design):
    specs, frames = recorded(design)
    per = run_metrics(from_recordings("gt", "test-1k", specs, frames), DYANA, design)
    expected = []
    for spec, f in zip(specs, frames):
        found = episode_hold(spec, f.palm_pose.astype(np.float64), f.joint_angles.astype(np.float64), design)
        expected.append(found[0] - spec.observe_frames if found and found[1].held else -1)
    assert per.t_hold.tolist() == expected
    # the opposable thumb's ground truth holds every one (benchmarks/results/hold_grasp_design.json: 1,000 of
    # 1,000); the splayed thumb's, the dataset's up to 4.x, none (0 of 400)
    assert (per.t_hold >= 0).all() if design is OPPOSED else (per.t_hold < 0).all()
    held = aggregate(per, np.zeros(len(specs), bool)).metrics["S_hold"]
    assert held == (100.0 if design is OPPOSED else 0.0)


def test_a_closed_hand_away_from_the_object_holds_nothing():
    specs, frames = recorded(OPPOSED)
    data = from_recordings("gt", "test-1k", specs, frames)
    per = run_metrics(data, DYANA, OPPOSED)
    assert (per.t_hold >= 0).all()
    # the same hands, the object somewhere else: nothing closes on it
    moved = [dataclasses.replace(f, palm_pose=f.palm_pose + np.array([3.0, 0, 0, 0, 0, 0], np.float32)) for f in frames]
    away = run_metrics(from_recordings("gt", "test-1k", specs, moved), DYANA, OPPOSED)
    assert (away.t_hold < 0).all() and (away.t_gra >= 0).all()


def test_a_folder_of_an_unknown_dataset_version_names_it():
    assert design_of("3.0.0") is design_of("4.0.0") is SPLAYED  # the splayed hand up to 4.x
    assert design_of(None) is design_of(DATASET_VERSION) is OPPOSED_WRIST
    with pytest.raises(SpecError, match=r"dataset version '9\.9\.9'"):
        design_of("9.9.9")
