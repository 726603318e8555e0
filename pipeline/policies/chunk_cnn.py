"""``chunk_cnn``: Dyana's learned baseline, a small image-conditioned policy with action chunks.

A LeRobot-style policy (``forward(batch) -> (loss, info)`` for training,
``select_action(batch)`` and ``reset()`` for the loop) trained on Dyana's own data
through ``catalog.open(..., keys="lerobot")`` by ``benchmarks/train_chunk_cnn.py``:

* **Input**: the current egocentric frame and the ``history`` frames before it, resized to
  ``image_size`` and stacked on channels, and ``observation.state`` (palm pose + joints),
  both normalised with the training folders' statistics. No text, no object pose.
* **Encoder**: four strided convolutions, then a spatial soft-argmax (the expected image
  position of each of 32 feature maps, as robomimic's visuomotor policies do): where
  things are is what interception needs.
* **Head**: an MLP on the keypoints and the state predicts a chunk of ``chunk`` future
  actions (palm xyz targets and 15 joint targets), normalised; the loss is the mean
  squared error over the chunk's real (unpadded) actions.
* **Acting**: the first ``n_action_steps`` actions of a predicted chunk are executed one per
  frame, then it predicts again (LeRobot's ACT/diffusion scheme).

torch is imported here; the module is only loaded when the policy is used.
"""

from __future__ import annotations

import json
import os
from collections import deque
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import torch
from torch import nn
from torch.nn import functional as F

from catalog.loader.lerobot_names import ACTION_KEY, IMAGE_KEY, STATE_KEY, pad_key
from schemas.errors import PolicyError
from schemas.names import printable


@dataclass(frozen=True)
class ChunkCNNConfig:
    history: int = 2
    image_size: tuple[int, int] = (96, 96)
    chunk: int = 10
    n_action_steps: int = 5
    keypoints: int = 32
    hidden: int = 256
    state_dim: int = 21
    action_dim: int = 18

    def __post_init__(self) -> None:
        if not 1 <= self.n_action_steps <= self.chunk:
            raise ValueError(f"n_action_steps must be in [1, chunk={self.chunk}], got {self.n_action_steps}")
        if self.history < 0:
            raise ValueError(f"history must be >= 0, got {self.history}")


class SpatialSoftArgmax(nn.Module):
    """(B, C, H, W) feature maps -> (B, 2C) expected (x, y) positions in [-1, 1]."""

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        b, c, h, w = features.shape
        weights = F.softmax(features.reshape(b, c, h * w), dim=-1).reshape(b, c, h, w)
        ys = torch.linspace(-1.0, 1.0, h, device=features.device, dtype=features.dtype)
        xs = torch.linspace(-1.0, 1.0, w, device=features.device, dtype=features.dtype)
        x = (weights.sum(dim=2) * xs).sum(dim=-1)
        y = (weights.sum(dim=3) * ys).sum(dim=-1)
        return torch.cat([x, y], dim=-1)


class ChunkCNNPolicy(nn.Module):
    """The baseline (module docstring). ``stats``: LeRobot-style statistics with ``mean``
    and ``std`` for ``observation.images.ego``, ``observation.state`` and ``action``."""

    name = "chunk_cnn"

    def __init__(self, config: ChunkCNNConfig, stats: dict[str, dict[str, Any]]) -> None:
        super().__init__()
        self.config = config
        channels = 3 * (config.history + 1)
        self.encoder = nn.Sequential(
            nn.Conv2d(channels, 32, 5, stride=2, padding=2), nn.ReLU(),
            nn.Conv2d(32, 64, 3, stride=2, padding=1), nn.ReLU(),
            nn.Conv2d(64, 64, 3, stride=1, padding=1), nn.ReLU(),
            nn.Conv2d(64, config.keypoints, 3, stride=1, padding=1),
        )
        self.keypoints = SpatialSoftArgmax()
        self.head = nn.Sequential(
            nn.Linear(2 * config.keypoints + config.state_dim * (config.history + 1), config.hidden), nn.ReLU(),
            nn.Linear(config.hidden, config.hidden), nn.ReLU(),
            nn.Linear(config.hidden, config.chunk * config.action_dim),
        )
        for key in (IMAGE_KEY, STATE_KEY, ACTION_KEY):
            mean = torch.as_tensor(stats[key]["mean"], dtype=torch.float32).reshape(-1)
            std = torch.as_tensor(stats[key]["std"], dtype=torch.float32).reshape(-1)
            self.register_buffer(f"{key.replace('.', '_')}_mean", mean)
            self.register_buffer(f"{key.replace('.', '_')}_std", torch.clamp(std, min=1e-3))
        self._queue: deque[torch.Tensor] = deque()

    def _buffer(self, name: str) -> torch.Tensor:
        value = getattr(self, name)
        assert isinstance(value, torch.Tensor)
        return value

    def _norm(self, key: str, value: torch.Tensor) -> torch.Tensor:
        name = key.replace(".", "_")
        return (value - self._buffer(f"{name}_mean")) / self._buffer(f"{name}_std")

    def _encode(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        images = batch[IMAGE_KEY]
        if images.dim() == 4:
            images = images.unsqueeze(1)
        b, t, c, h, w = images.shape
        mean = self._buffer("observation_images_ego_mean").reshape(1, 1, c, 1, 1)
        std = self._buffer("observation_images_ego_std").reshape(1, 1, c, 1, 1)
        stacked = ((images - mean) / std).reshape(b, t * c, h, w)
        state = self._norm(STATE_KEY, batch[STATE_KEY]).reshape(b, -1)
        return torch.cat([self.keypoints(self.encoder(stacked)), state], dim=-1)

    def predict_chunk(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        """(B, chunk, 18) actions, unnormalised."""
        out = self.head(self._encode(batch)).reshape(-1, self.config.chunk, self.config.action_dim)
        return out * self._buffer("action_std") + self._buffer("action_mean")

    def forward(self, batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, dict[str, float]]:
        """Training loss: mean squared error of the normalised chunk over unpadded actions."""
        predicted = self.head(self._encode(batch)).reshape(-1, self.config.chunk, self.config.action_dim)
        target = self._norm(ACTION_KEY, batch[ACTION_KEY])
        keep = (~batch[pad_key(ACTION_KEY)]).unsqueeze(-1).to(predicted.dtype)
        loss = (((predicted - target) ** 2) * keep).sum() / (keep.sum() * self.config.action_dim).clamp(min=1.0)
        return loss, {"loss": float(loss.detach())}

    def reset(self) -> None:
        self._queue.clear()

    @torch.no_grad()
    def select_action(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        if not self._queue:
            chunk = self.predict_chunk(batch)[:, : self.config.n_action_steps]
            self._queue.extend(chunk.transpose(0, 1))
        return self._queue.popleft()

    # checkpoints ------------------------------------------------------------------------
    def save(self, directory: str | os.PathLike[str], record: dict[str, Any] | None = None) -> Path:
        """Write ``config.json`` and ``model.pt`` (weights and normalisation buffers)."""
        folder = Path(directory)
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "config.json").write_text(json.dumps({"config": asdict(self.config), "record": record or {}},
                                                       indent=2, sort_keys=True) + "\n")
        torch.save(self.state_dict(), folder / "model.pt")
        return folder

    @classmethod
    def load(cls, directory: str | os.PathLike[str]) -> ChunkCNNPolicy:
        folder = Path(directory)
        meta = json.loads((folder / "config.json").read_text())
        values = meta["config"]
        values["image_size"] = tuple(values["image_size"])
        config = ChunkCNNConfig(**values)
        state = torch.load(folder / "model.pt", map_location="cpu", weights_only=True)
        blank = {key: {"mean": torch.zeros(n), "std": torch.ones(n)}
                 for key, n in ((IMAGE_KEY, 3), (STATE_KEY, config.state_dim), (ACTION_KEY, config.action_dim))}
        policy = cls(config, blank)
        policy.load_state_dict(state)
        policy.eval()
        return policy


#: Where ``pretrained`` looks for the checkpoint unless ``DYANA_CHUNK_CNN`` names another
#: (a checkout's; the wheel does not carry it).
DEFAULT_CHECKPOINT = Path(__file__).resolve().parents[2] / "benchmarks" / "results" / "chunk_cnn"


def pretrained():
    """``pipeline eval --policy pipeline.policies.chunk_cnn:pretrained``: the trained baseline
    (``benchmarks/train_chunk_cnn.py``), from ``$DYANA_CHUNK_CNN`` or the committed checkpoint."""
    from pipeline.policies.lerobot_adapter import LeRobotAdapter

    folder = Path(os.environ.get("DYANA_CHUNK_CNN", DEFAULT_CHECKPOINT))
    if not (folder / "config.json").is_file() or not (folder / "model.pt").is_file():
        # An installed wheel has none: the committed one is a checkout's benchmarks/results/chunk_cnn.
        raise PolicyError(f"chunk_cnn: no checkpoint (config.json, model.pt) in {printable(str(folder))}; "
                          "set DYANA_CHUNK_CNN")
    policy = ChunkCNNPolicy.load(folder)
    torch.set_num_threads(1)
    return LeRobotAdapter(policy, "chunk_cnn", history=policy.config.history, image_size=policy.config.image_size)
