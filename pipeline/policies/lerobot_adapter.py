"""A LeRobot-style torch policy in Dyana's closed loop.

LeRobot policies (ACT, diffusion, SmolVLA, ... and Dyana's own ``chunk_cnn`` baseline)
share one interface: ``reset()`` before an episode and ``select_action(batch)``, which
takes a batch of observations keyed as LeRobot keys them and returns the next action
(1, action_dim), keeping its own queue of a predicted action chunk. :class:`LeRobotAdapter`
makes such an object a Dyana policy:

* **Observations** are keyed exactly as ``catalog.open(..., keys="lerobot")`` keys the
  training data (:func:`catalog.loader.lerobot_keys.observation_features`): the egocentric
  image as (1, 3, H, W) float32 in [0, 1], ``observation.state`` (1, 21), ``task``.
  ``observation.environment_state`` (the object's true pose) is training data only:
  the loop never shows it to a policy. With ``history=K`` the adapter stacks the K
  previous frames as the loader does (``(1, K+1, 3, H, W)`` and ``..._is_pad``), starting
  from the observe window's frames and padding with the first frame.
* **Resizing**: ``image_size=(h, w)`` resizes like ``catalog.open(resize=...)``
  (``cv2.INTER_AREA``), so a policy trained on resized frames sees the same pixels.
* **Actions**: one (18,) action per frame; chunking is the policy's own business
  (its ``select_action`` queue), as in LeRobot's own evaluation loop.
* **Device**: ``device="cpu"`` by default; tensors are moved there and actions come back
  as float32 numpy. Inference runs under ``torch.inference_mode``.

To evaluate a checkpoint: write a factory returning ``LeRobotAdapter(policy, ...)`` and
run ``pipeline eval --policy mymodule:factory`` (docs/guides/your-policy.md).
"""

from __future__ import annotations

from collections import deque
from typing import Any

import cv2
import numpy as np

from catalog.loader.lerobot_keys import observation_features
from catalog.loader.lerobot_names import IMAGE_KEY, STATE_KEY, pad_key
from pipeline.policies.base import Observation, Task
from schemas.errors import PolicyError


class LeRobotAdapter:
    """Wrap an object with ``reset()`` and ``select_action(batch) -> (1, 18)`` as a Dyana policy."""

    privileged = False
    action_horizon = 1

    def __init__(
        self,
        policy: Any,
        name: str = "lerobot",
        *,
        device: str = "cpu",
        history: int = 0,
        image_size: tuple[int, int] | None = None,
    ) -> None:
        import torch

        if not callable(getattr(policy, "select_action", None)) or not callable(getattr(policy, "reset", None)):
            raise PolicyError(f"{name}: a LeRobot-style policy needs reset() and select_action(batch)")
        if isinstance(history, bool) or not isinstance(history, int) or history < 0:
            raise PolicyError(f"{name}: history must be an integer >= 0, got {history!r}")
        self.torch = torch
        self.policy = policy
        self.name = name
        self.device = torch.device(device)
        self.history = history
        self.image_size = image_size
        self._text = ""
        self._frames: deque[dict[str, np.ndarray]] = deque(maxlen=history + 1)
        self._pads: deque[bool] = deque(maxlen=history + 1)

    def reset(self, task: Task) -> None:
        self.policy.reset()
        self._text = str(task.get("text", ""))
        self._frames.clear()
        self._pads.clear()

    def _features(self, image: np.ndarray, obs: Observation) -> dict[str, np.ndarray]:
        if self.image_size is not None:
            height, width = self.image_size
            if image.shape[:2] != (height, width):
                image = cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)
        return observation_features(image, np.asarray(obs["palm_pose"], np.float32),
                                    np.asarray(obs["joint_angles"], np.float32))

    def _push(self, obs: Observation) -> None:
        if not self._frames:
            earlier = list(obs.get("observe_images", []))[-self.history:] if self.history else []
            first = earlier[0] if earlier else obs["image"]
            for _ in range(self.history - len(earlier)):
                self._frames.append(self._features(first, obs))
                self._pads.append(True)
            for image in earlier:
                self._frames.append(self._features(image, obs))  # the hand rests while observed
                self._pads.append(False)
        self._frames.append(self._features(obs["image"], obs))
        self._pads.append(False)

    def batch(self, obs: Observation) -> dict[str, Any]:
        """The observation as a batch of one, on the adapter's device."""
        torch = self.torch
        self._push(obs)
        out: dict[str, Any] = {"task": [self._text]}
        if self.history == 0:
            current = self._frames[-1]
            for key, value in current.items():
                out[key] = torch.from_numpy(value).unsqueeze(0).to(self.device)
            return out
        for key in (IMAGE_KEY, STATE_KEY):
            stacked = np.stack([frame[key] for frame in self._frames])
            out[key] = torch.from_numpy(stacked).unsqueeze(0).to(self.device)
            out[pad_key(key)] = torch.tensor([list(self._pads)], dtype=torch.bool, device=self.device)
        return out

    def act(self, obs: Observation) -> np.ndarray:
        batch = self.batch(obs)
        with self.torch.inference_mode():
            action = self.policy.select_action(batch)
        values = np.asarray(action.detach().to("cpu").numpy() if hasattr(action, "detach") else action, np.float32)
        if values.shape not in ((1, 18), (18,)):
            raise PolicyError(f"{self.name}: select_action gave shape {values.shape}, expected (1, 18)")
        return values.reshape(18)
