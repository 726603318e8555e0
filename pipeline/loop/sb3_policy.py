"""A saved Stable-Baselines3 model as a Dyana policy: ``pipeline eval --policy sb3:MODEL.zip``.

The reference is ``sb3:PATH`` (or ``sb3:ALGO:PATH``). SB3's zip does not name the
algorithm that saved it, so it is read from the zip's ``data``, nothing unpickled: a
``sac`` or ``td3`` policy class is SAC or TD3, an actor-critic one PPO if it has PPO's
``clip_range``, else A2C. A DDPG model's zip is a TD3 policy's: ``sb3:DDPG:PATH`` records
it as DDPG (it predicts the same); an ``ALGO`` the zip contradicts is refused. The model is
loaded with that class's ``load`` on the CPU (torch on one thread, as the eval workers
are), and every action is ``predict(view, deterministic=True)``.

What the model was trained on comes from the spaces the zip holds, as
:class:`~pipeline.loop.env.DyanaEnv` makes them (:mod:`pipeline.loop.views`):

* **the view**: a uint8 image Box (H, W, 3), or (3, H, W) as SB3 transposes it, is
  ``obs="image"``; a 148-wide float Box ``"state"``; a Dict of the two ``"both"``. The
  full observation is built into that view with the env's own functions, so the model sees
  what it saw in training. An image view needs ``pipeline eval --resolution`` equal to the
  image's side (an episode at another resolution is refused: a fault naming both);
* **the action**: the Box [-1, 1]^18 is ``normalize_actions=True`` (mapped back with
  :func:`~pipeline.loop.views.absolute_action`), the real action Box is the dataset's
  absolute targets. Any other space is refused before the run starts.

The run's manifest records (``sb3``) the zip's sha256, the algorithm, the view, the
resolution, ``normalize_actions`` and the SB3 version that saved it; a zip changed since
the run started is refused.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from catalog.store.hashing import sha256_file
from pipeline.loop.actions import as_action
from pipeline.loop.spaces import action_space
from pipeline.loop.views import STATE_WIDTH, VIEWS, absolute_action, normalized_action_space
from pipeline.policies.base import Observation, Task
from schemas.errors import PolicyError, SpecError
from schemas.names import shorten

PREFIX = "sb3:"
#: The algorithms ``sb3:ALGO:PATH`` names (Box actions: the ones that can drive the hand).
ALGOS = ("PPO", "A2C", "SAC", "TD3", "DDPG")
INSTALL = "pip install -c .ci/constraints.txt -e '.[sb3]' (it needs torch)"


def split_ref(ref: str) -> tuple[str | None, str]:
    """``sb3:[ALGO:]PATH`` as (ALGO upper-cased or None, PATH); SpecError on an empty path."""
    rest = ref[len(PREFIX):] if ref.startswith(PREFIX) else ref
    head, sep, tail = rest.partition(":")
    algo, path = (head.upper(), tail) if sep and head.upper() in ALGOS else (None, rest)
    if not path:
        raise SpecError(f"--policy {shorten(repr(ref))}: expected sb3:MODEL.zip or sb3:ALGO:MODEL.zip "
                        f"(ALGO one of {', '.join(ALGOS)})")
    return algo, path


def read_data(path: str) -> dict[str, Any]:
    """The zip's ``data`` (JSON, nothing unpickled); PolicyError if it is not an SB3 model."""
    name = shorten(path)
    file = Path(path).expanduser()
    if not file.is_file():
        raise PolicyError(f"{name}: no such Stable-Baselines3 model file")
    try:
        with zipfile.ZipFile(file) as archive:
            data = json.loads(archive.read("data"))
    except zipfile.BadZipFile:
        raise PolicyError(f"{name}: not a Stable-Baselines3 model (not a zip file)") from None
    except KeyError:
        raise PolicyError(f"{name}: not a Stable-Baselines3 model (no 'data' in the zip)") from None
    except (OSError, ValueError, RecursionError) as exc:
        raise PolicyError(f"{name}: unreadable Stable-Baselines3 model ({shorten(str(exc))})") from None
    if not isinstance(data, dict) or not all(k in data for k in ("policy_class", "observation_space", "action_space")):
        raise PolicyError(f"{name}: not a Stable-Baselines3 model (its data has no policy class or spaces)")
    return data


def infer_algo(path: str, data: dict[str, Any]) -> str:
    """The algorithm a saved model's ``data`` implies (see the module docstring)."""
    policy = data["policy_class"]
    module = str(policy.get("__module__", "")) if isinstance(policy, dict) else ""
    family = module.split(".")[1] if module.startswith("stable_baselines3.") else ""
    if family in ("sac", "td3"):
        return family.upper()
    if family == "common" and "gae_lambda" in data:
        return "PPO" if "clip_range" in data else "A2C"
    raise PolicyError(f"{shorten(path)}: not saved by one of {', '.join(ALGOS)} (its policy class comes from "
                      f"{shorten(module or '?')})")


def view_of(path: str, space: Any) -> tuple[str, int | None]:
    """The ``obs`` view (and image side, None for ``state``) a model's observation space is."""
    from gymnasium import spaces

    def image_side(box: Any) -> int | None:
        if not isinstance(box, spaces.Box) or box.dtype != np.uint8 or len(box.shape) != 3:
            return None
        height, width, channels = box.shape if box.shape[-1] == 3 else (*box.shape[1:], box.shape[0])
        return int(height) if channels == 3 and height == width else None

    def is_state(box: Any) -> bool:
        return isinstance(box, spaces.Box) and box.shape == (STATE_WIDTH,)

    if isinstance(space, spaces.Dict) and set(space.spaces) == {"image", "state"}:
        side = image_side(space["image"])
        if side is not None and is_state(space["state"]):
            return "both", side
    elif is_state(space):
        return "state", None
    elif (side := image_side(space)) is not None:
        return "image", side
    raise PolicyError(f"{shorten(path)}: observation space {shorten(str(space))} is none of DyanaEnv's views "
                      "(obs='image', 'state' or 'both')")


def normalized_of(path: str, space: Any) -> bool:
    """Whether a model's action space is ``normalize_actions=True``'s (else the real one's)."""
    for normalized, box in ((True, normalized_action_space()), (False, action_space())):
        if (getattr(space, "shape", None) == box.shape and np.array_equal(space.low, box.low)
                and np.array_equal(space.high, box.high)):
            return normalized
    raise PolicyError(f"{shorten(path)}: action space {shorten(str(space))} is neither [-1, 1]^18 "
                      "(normalize_actions=True) nor Dyana's action Box")


def load_model(path: str, algo: str) -> Any:
    """The saved model, loaded with ``algo``'s class on the CPU."""
    try:
        import stable_baselines3
    except ImportError as exc:
        raise PolicyError(f"sb3:PATH needs Stable-Baselines3 ({shorten(str(exc))}): {INSTALL}") from None
    try:
        return getattr(stable_baselines3, algo).load(str(Path(path).expanduser()), device="cpu")
    except Exception as exc:  # whatever a foreign zip makes SB3 raise: one line
        raise PolicyError(f"{shorten(path)}: Stable-Baselines3 could not load it as {algo} "
                          f"({type(exc).__name__}: {shorten(str(exc))})") from None


def configure(ref: str, config: dict[str, Any] | None) -> dict[str, Any]:
    """The kind's configuration, recorded in the run's manifest: the zip's sha256, the
    algorithm, the view, its resolution, ``normalize_actions`` and the SB3 version. Loads
    the model once, so a zip SB3 cannot load fails before the run starts."""
    if config is not None:
        raise SpecError(f"{shorten(ref)}: an sb3: policy takes no --model, --vlm-* or --policy-device flags")
    named, path = split_ref(ref)
    algo = infer_algo(path, read_data(path))
    if named is not None and named != algo:
        if (named, algo) != ("DDPG", "TD3"):
            raise PolicyError(f"{shorten(path)}: saved by {algo}, not {named} (its data says so): "
                              f"sb3:{path} reads the algorithm from the zip")
        algo = named
    model = load_model(path, algo)
    view, side = view_of(path, model.observation_space)
    normalized = normalized_of(path, model.action_space)
    with zipfile.ZipFile(Path(path).expanduser()) as archive:
        names = archive.namelist()
        version = archive.read("_stable_baselines3_version").decode().strip() if "_stable_baselines3_version" in names else None
    return {"model": Path(path).name, "sha256": sha256_file(Path(path).expanduser()), "algo": algo, "obs": view,
            "resolution": side, "normalize_actions": normalized, "saved_by": version}


@dataclass(frozen=True)
class SB3Policy:
    """A loaded model behind Dyana's policy protocol (one action per step)."""

    model: Any
    view: str
    resolution: int | None
    normalize_actions: bool
    name: str
    action_horizon: int = 1
    privileged: bool = False

    def __post_init__(self) -> None:
        if self.view not in VIEWS or self.view == "full":
            raise SpecError(f"SB3Policy: view must be 'image', 'state' or 'both', got {shorten(repr(self.view))}")
        if (self.resolution is None) != (self.view == "state"):
            raise SpecError(f"SB3Policy: an image view needs its resolution (and 'state' none), "
                            f"got {self.view!r} at {shorten(repr(self.resolution))}")

    def reset(self, task: Task) -> None:
        if self.resolution is not None and task["resolution"] != self.resolution:
            raise PolicyError(f"{self.name}: trained on {self.resolution} px images, the run renders "
                              f"{task['resolution']} px: pass --resolution {self.resolution}")

    def act(self, obs: Observation) -> np.ndarray:
        action, _ = self.model.predict(VIEWS[self.view].show(obs), deterministic=True)
        return absolute_action(action) if self.normalize_actions else as_action(action)


def make(ref: str, config: dict[str, Any] | None) -> SB3Policy:
    """The policy of ``sb3:[ALGO:]PATH`` (``config`` as :func:`configure` made it, or None)."""
    config = configure(ref, None) if config is None else config
    path = split_ref(ref)[1]
    read_data(path)  # still there, still a model
    if sha256_file(Path(path).expanduser()) != config["sha256"]:
        raise PolicyError(f"{shorten(path)} changed since the run started")
    name = f"sb3-{config['algo'].lower()}-{config['sha256'][:8]}"
    import torch  # stable_baselines3 imported it

    torch.set_num_threads(1)  # the workers are single-threaded; one thread, one summation order
    return SB3Policy(load_model(path, config["algo"]), config["obs"], config["resolution"],
                     config["normalize_actions"], name)
