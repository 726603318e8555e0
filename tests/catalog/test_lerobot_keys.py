"""``catalog.open(..., keys="lerobot")``: LeRobot's keys, shapes and dtypes over Dyana's reader."""

from __future__ import annotations

import numpy as np
import pytest

import catalog
from schemas.errors import SpecError
from tests.catalog.conftest import write_slice

LEROBOT_KEYS = {
    "observation.images.ego", "observation.state", "observation.environment_state", "action", "timestamp",
    "frame_index", "episode_index", "index", "task_index", "task",
}


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    root = tmp_path_factory.mktemp("keys") / "linear-fast"
    write_slice(root, episodes=4, shard_size=2)
    return root


def test_items_carry_lerobots_keys_and_the_same_values(built):
    with catalog.open(built) as plain, catalog.open(built, keys="lerobot") as keyed:
        assert len(plain) == len(keyed)
        for i in (0, 7, len(plain) - 1):
            a, b = plain[i], keyed[i]
            assert set(b) == LEROBOT_KEYS
            image = b["observation.images.ego"]
            assert image.dtype == np.float32 and image.shape == (3,) + a["image"].shape[:2]
            np.testing.assert_array_equal(image, a["image"].transpose(2, 0, 1).astype(np.float32) / np.float32(255))
            np.testing.assert_array_equal(b["observation.state"], np.concatenate([a["palm_pose"], a["joint_angles"]]))
            np.testing.assert_array_equal(b["observation.environment_state"], a["object_pose"])
            np.testing.assert_array_equal(b["action"], a["action"])
            assert b["index"] == i and b["frame_index"] == a["frame_index"] and b["task"] == a["text"]
            assert b["task_index"] == keyed.tasks[a["text"]]
            assert b["timestamp"].dtype == np.float32


def test_history_and_horizon_windows_keep_their_pad_flags(built):
    with catalog.open(built, keys="lerobot", history=2, action_horizon=5, image_dtype="uint8") as ds:
        item = ds[0]
        assert item["observation.images.ego"].dtype == np.uint8 and item["observation.images.ego"].shape[:2] == (3, 3)
        assert item["observation.state"].shape == (3, 21) and item["action"].shape == (5, 18)
        assert item["observation.images.ego_is_pad"].tolist() == [True, True, False]
        assert item["observation.state_is_pad"].tolist() == [True, True, False]
        assert item["action_is_pad"].tolist() == [False] * 5


def test_task_indices_survive_a_selection(built):
    with catalog.open(built, keys="lerobot") as ds:
        last = ds.select(episodes=[3])
        text = last[0]["task"]
        assert last[0]["task_index"] == ds.tasks[text] and last.tasks == ds.tasks


@pytest.mark.parametrize("bad", [dict(keys="hf"), dict(image_dtype="float16")])
def test_unknown_keys_or_image_types_are_refused(built, bad):
    with pytest.raises(SpecError, match=next(iter(bad))):
        catalog.open(built, **bad)
