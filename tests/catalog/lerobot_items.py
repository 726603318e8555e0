"""Run by a Python that has the real ``lerobot`` package (see test_export_lerobot.py):
load an export with ``LeRobotDataset`` and save every item's arrays to an .npz.

    python lerobot_items.py EXPORT_DIR OUT.npz [VIDEO_BACKEND]
"""

import sys

import numpy as np
from lerobot.datasets.lerobot_dataset import LeRobotDataset

root, out = sys.argv[1], sys.argv[2]
backend = sys.argv[3] if len(sys.argv) > 3 else None
dataset = LeRobotDataset("dyana/export", root=root, video_backend=backend)
items = [dataset[i] for i in range(len(dataset))]
arrays = {
    key: np.stack([np.asarray(item[key]) for item in items])
    for key in ("observation.state", "observation.environment_state", "action", "timestamp", "frame_index",
                "episode_index", "index", "task_index")
}
images = np.stack([np.asarray(item["observation.images.ego"]) for item in items])  # (n, 3, H, W) float in [0, 1]
arrays["image"] = np.clip(np.round(images.transpose(0, 2, 3, 1) * 255.0), 0, 255).astype(np.uint8)
arrays["task"] = np.array([item["task"] for item in items])
arrays["num_episodes"] = np.array(dataset.num_episodes)
arrays["keys"] = np.array(sorted(items[0]))
arrays["image_shape"] = np.array(tuple(items[0]["observation.images.ego"].shape))
arrays["state_mean"] = np.asarray(dataset.meta.stats["observation.state"]["mean"])
np.savez(out, **arrays)
import lerobot  # noqa: E402

print(lerobot.__version__ if hasattr(lerobot, "__version__") else "unknown")
