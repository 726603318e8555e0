"""A fake ``lerobot`` with the API :mod:`pipeline.policies.lerobot_checkpoint` uses, in the
two normalisation styles, and checkpoint folders shaped as ``lerobot-train`` saves them.

LeRobot 0.3.x style (``processors=False``): the model holds the action statistics and
un-normalises its own output. LeRobot >= 0.4 style: the model outputs normalised actions,
``policy_postprocessor.json`` holds the statistics and ``make_pre_post_processors`` exists.
The fake policy drives the palm to :data:`TARGET` and checks every batch it is given (the
keys its config declares, the image's shape, the state normalised in the 0.4 style).
"""

from __future__ import annotations

import json
import sys
import types
from pathlib import Path
from typing import Any

import pytest
import torch

TARGET = torch.tensor([0.5, 1.2, 3.0] + [0.1] * 15)
ACTION_MEAN, ACTION_STD = 1.0, 2.0
STATE_MEAN, STATE_STD = 0.25, 4.0
IMAGE_KEY = "observation.images.front"


def write_checkpoint(folder: Path, *, processors: bool, size: tuple[int, int] = (32, 32),
                     extra_inputs: dict[str, Any] | None = None, state: bool = True) -> Path:
    """A checkpoint folder (``pretrained_model``) in one of the two styles."""
    folder.mkdir(parents=True, exist_ok=True)
    inputs: dict[str, Any] = {IMAGE_KEY: {"type": "VISUAL", "shape": [3, *size]}}
    if state:
        inputs["observation.state"] = {"type": "STATE", "shape": [21]}
    inputs.update(extra_inputs or {})
    config = {"type": "fake", "device": "cuda", "pretrained_backbone_weights": "ResNet18_Weights.IMAGENET1K_V1",
              "input_features": inputs, "output_features": {"action": {"type": "ACTION", "shape": [18]}}}
    (folder / "config.json").write_text(json.dumps(config))
    normalised = ((TARGET - ACTION_MEAN) / ACTION_STD).tolist()
    model: dict[str, Any] = {"normalised_target": normalised}
    if processors:
        (folder / "policy_preprocessor.json").write_text(json.dumps({"state_mean": STATE_MEAN, "state_std": STATE_STD}))
        (folder / "policy_postprocessor.json").write_text(json.dumps({"mean": ACTION_MEAN, "std": ACTION_STD}))
    else:
        model |= {"mean": ACTION_MEAN, "std": ACTION_STD}
    (folder / "model.safetensors").write_text(json.dumps(model))
    return folder


class FakeConfig(types.SimpleNamespace):
    @classmethod
    def from_pretrained(cls, folder: str) -> FakeConfig:
        return cls(**json.loads((Path(folder) / "config.json").read_text()))


class FakePolicy:
    """Selects the checkpoint's target every frame; checks the batches."""

    calls: list[dict[str, Any]] = []

    def __init__(self, config: FakeConfig, model: dict[str, Any], processors: bool) -> None:
        self.config, self.model, self.processors = config, model, processors
        self.resets = 0

    @classmethod
    def from_pretrained(cls, folder: str, config: FakeConfig) -> FakePolicy:
        assert config.pretrained_backbone_weights is None, "loading a checkpoint must not download backbone weights"
        assert config.device == "cpu"
        return cls(config, json.loads((Path(folder) / "model.safetensors").read_text()),
                   (Path(folder) / "policy_preprocessor.json").is_file())

    def eval(self) -> FakePolicy:
        return self

    def reset(self) -> None:
        self.resets += 1

    def select_action(self, batch: dict[str, Any]) -> torch.Tensor:
        assert set(batch) == set(self.config.input_features) | {"task"}, sorted(batch)
        shape = self.config.input_features[IMAGE_KEY]["shape"]
        assert tuple(batch[IMAGE_KEY].shape) == (1, *shape)
        FakePolicy.calls.append({k: v.clone() if isinstance(v, torch.Tensor) else v for k, v in batch.items()})
        action = torch.tensor(self.model["normalised_target"]).unsqueeze(0)
        if not self.processors:
            action = action * self.model["std"] + self.model["mean"]
        return action


class Normalise:
    """The fake preprocessor: the state standardised with the saved statistics."""

    def __init__(self, stats: dict[str, float]) -> None:
        self.stats = stats

    def __call__(self, batch: dict[str, Any]) -> dict[str, Any]:
        out = dict(batch)
        if "observation.state" in out:
            out["observation.state"] = (out["observation.state"] - self.stats["state_mean"]) / self.stats["state_std"]
        return out


class Unnormalise:
    def __init__(self, stats: dict[str, float]) -> None:
        self.stats = stats

    def __call__(self, action: torch.Tensor) -> torch.Tensor:
        return action * self.stats["std"] + self.stats["mean"]


def install(monkeypatch: pytest.MonkeyPatch, *, processors: bool) -> None:
    """Put the fake ``lerobot`` (0.3 style without ``make_pre_post_processors``, 0.4 style
    with) into ``sys.modules`` for this test."""
    FakePolicy.calls = []
    root, configs, policies = (types.ModuleType(n) for n in ("lerobot", "lerobot.configs", "lerobot.policies"))
    config_module, factory = types.ModuleType("lerobot.configs.policies"), types.ModuleType("lerobot.policies.factory")
    config_module.PreTrainedConfig = FakeConfig  # type: ignore[attr-defined]
    factory.get_policy_class = lambda name: FakePolicy  # type: ignore[attr-defined]
    if processors:
        def make_pre_post_processors(policy_cfg: FakeConfig, pretrained_path: str,
                                     preprocessor_overrides: dict[str, Any]) -> tuple[Normalise, Unnormalise]:
            assert preprocessor_overrides == {"device_processor": {"device": policy_cfg.device}}
            folder = Path(pretrained_path)
            return (Normalise(json.loads((folder / "policy_preprocessor.json").read_text())),
                    Unnormalise(json.loads((folder / "policy_postprocessor.json").read_text())))

        factory.make_pre_post_processors = make_pre_post_processors  # type: ignore[attr-defined]
    root.configs, root.policies = configs, policies  # type: ignore[attr-defined]
    configs.policies, policies.factory = config_module, factory  # type: ignore[attr-defined]
    for name, module in (("lerobot", root), ("lerobot.configs", configs), ("lerobot.policies", policies),
                         ("lerobot.configs.policies", config_module), ("lerobot.policies.factory", factory)):
        monkeypatch.setitem(sys.modules, name, module)
