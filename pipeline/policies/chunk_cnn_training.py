"""Training ``chunk_cnn`` on built Dyana folders, through ``catalog.open(..., keys="lerobot")``.

Only acting frames are trained on (the closed loop never asks a policy during the
observe window, whose frames all show the hand at rest). Batches come from a torch
``DataLoader`` over the keyed dataset with a seeded sampler; the image statistics are
measured on an evenly spaced sample of frames, the state and action statistics are the
folders' own ``stats.json``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch
from torch.utils.data import DataLoader, Subset

import catalog
from catalog.loader.lerobot_names import ACTION_KEY, IMAGE_KEY, STATE_KEY, VECTOR_SOURCES, pad_key
from pipeline.policies.chunk_cnn import ChunkCNNConfig, ChunkCNNPolicy


def acting_positions(dataset: Any) -> list[int]:
    """Positions of every acting frame (past each episode's observe window)."""
    positions: list[int] = []
    for k, episode in enumerate(dataset.episodes):
        frames = dataset.episode_frames(k)
        positions.extend(frames[episode.observe_frames:])
    return positions


def _vector_stats(stats: Any, names: Sequence[str]) -> dict[str, np.ndarray]:
    return {
        "mean": np.concatenate([stats[name].mean for name in names]),
        "std": np.concatenate([stats[name].std for name in names]),
    }


def normalisation(dataset: Any, sample: int = 400) -> dict[str, dict[str, np.ndarray]]:
    """Statistics for the policy: image channels from ``sample`` evenly spaced frames; state
    (palm pose + joints) and action from the folders' statistics."""
    positions = np.linspace(0, len(dataset) - 1, min(sample, len(dataset))).round().astype(int)
    images = [dataset[int(p)][IMAGE_KEY] for p in positions]
    pixels = np.stack([image[-1] if image.ndim == 4 else image for image in images])  # the current frame
    channels = pixels.transpose(1, 0, 2, 3).reshape(3, -1).astype(np.float64)
    return {
        IMAGE_KEY: {"mean": channels.mean(axis=1), "std": channels.std(axis=1)},
        STATE_KEY: _vector_stats(dataset.stats, VECTOR_SOURCES[STATE_KEY]),
        ACTION_KEY: _vector_stats(dataset.stats, VECTOR_SOURCES[ACTION_KEY]),
    }


def train(
    folders: Sequence[str],
    config: ChunkCNNConfig,
    *,
    epochs: int,
    batch_size: int = 64,
    lr: float = 1e-3,
    seed: int = 0,
    workers: int = 1,
    max_steps: int | None = None,
    progress: Callable[[str], None] | None = None,
) -> tuple[ChunkCNNPolicy, dict[str, Any]]:
    """Train a fresh policy on the acting frames of ``folders``; returns it and a record of
    the run (data size, steps, seconds, losses, seed, versions)."""
    start = time.perf_counter()
    torch.manual_seed(seed)
    dataset = catalog.open(list(folders), history=config.history, action_horizon=config.chunk,
                           resize=config.image_size, keys="lerobot")
    positions = acting_positions(dataset)
    policy = ChunkCNNPolicy(config, normalisation(dataset))
    policy.train()
    generator = torch.Generator().manual_seed(seed)
    loader = DataLoader(
        Subset(dataset.torch(), positions), batch_size=batch_size, shuffle=True, generator=generator,
        num_workers=workers, persistent_workers=workers > 0, drop_last=len(positions) > batch_size,
    )
    optimiser = torch.optim.AdamW(policy.parameters(), lr=lr, weight_decay=1e-4)
    total_steps = epochs * len(loader) if max_steps is None else min(max_steps, epochs * len(loader))
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, T_max=max(total_steps, 1))
    keys = (IMAGE_KEY, STATE_KEY, ACTION_KEY, pad_key(ACTION_KEY))
    losses: list[float] = []
    step = 0
    for epoch in range(epochs):
        epoch_loss, batches = 0.0, 0
        for batch in loader:
            loss, _ = policy({key: batch[key] for key in keys})
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            optimiser.step()
            schedule.step()
            epoch_loss += float(loss.detach())
            batches += 1
            step += 1
            if step >= total_steps:
                break
        losses.append(epoch_loss / max(batches, 1))
        if progress is not None:
            progress(f"[epoch {epoch + 1}/{epochs}] loss {losses[-1]:.4f}, {step} steps, "
                     f"{time.perf_counter() - start:.0f} s")
        if step >= total_steps:
            break
    policy.eval()
    dataset.close()
    record = {
        "folders": [str(f) for f in folders],
        "episodes": len(dataset.episodes),
        "training_frames": len(positions),
        "epochs": epochs,
        "steps": step,
        "batch_size": batch_size,
        "lr": lr,
        "seed": seed,
        "epoch_losses": [round(v, 5) for v in losses],
        "seconds": round(time.perf_counter() - start, 1),
        "torch": torch.__version__,
    }
    return policy, record
