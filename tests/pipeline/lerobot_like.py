"""A LeRobot-style policy object (reset / select_action over keyed batches) for the adapter
tests: it moves the palm straight to a fixed point and closes nothing, and checks every
batch it is given. ``make`` is the factory ``pipeline eval --policy`` calls."""

from __future__ import annotations

import torch

from pipeline.policies.lerobot_adapter import LeRobotAdapter

TARGET = torch.tensor([0.5, 1.2, 3.0] + [0.1] * 15)


class PointPolicy:
    def __init__(self) -> None:
        self.batches: list[dict] = []
        self.resets = 0

    def reset(self) -> None:
        self.resets += 1

    def select_action(self, batch: dict) -> torch.Tensor:
        image, state = batch["observation.images.ego"], batch["observation.state"]
        assert image.dtype == torch.float32 and image.dim() == 4 and image.shape[:2] == (1, 3)
        assert 0.0 <= float(image.min()) and float(image.max()) <= 1.0
        assert state.shape == (1, 21) and isinstance(batch["task"][0], str)
        assert "observation.environment_state" not in batch, "the loop never shows the object's pose"
        self.batches.append(batch)
        return TARGET.unsqueeze(0)


class WrongShape(PointPolicy):
    def select_action(self, batch: dict) -> torch.Tensor:
        return torch.zeros(1, 7)


def make() -> LeRobotAdapter:
    return LeRobotAdapter(PointPolicy(), "point")


def make_wrong() -> LeRobotAdapter:
    return LeRobotAdapter(WrongShape(), "wrong-shape")
