"""A LeRobot checkpoint as a Dyana policy: ``pipeline eval --policy lerobot:PATH``.

``PATH`` is a ``pretrained_model`` folder as ``lerobot-train`` saves it (``config.json``,
``model.safetensors``, ``train_config.json``), or a training output or checkpoint folder
holding one (``checkpoints/last/pretrained_model`` is found). The policy is loaded with the
lerobot installed in the running Python (imported when first used):

* **Inputs** come from the checkpoint's ``config.json`` ``input_features``, read before
  lerobot is imported: its one ``VISUAL`` feature gets Dyana's egocentric image (whatever
  its key; resized with ``cv2.INTER_AREA`` to the feature's shape), ``observation.state``
  (21) the palm pose and joint angles. Any other input (``observation.environment_state``,
  the object's true pose, is privileged: the loop never shows it) is refused up front,
  naming it; so is an ``action`` output that is not 18 wide.
* **Normalisation**: a folder with ``policy_preprocessor.json`` (LeRobot >= 0.4) is run
  through its saved pre- and post-processors (``make_pre_post_processors``); a folder
  without (LeRobot 0.3.x) normalises inside the model. A checkpoint whose style the
  installed lerobot does not run is refused, saying what to install or migrate.
* **Actions**: ``select_action`` gives one action per frame; a chunk policy (ACT,
  Diffusion) keeps its own queue of predicted actions, as in LeRobot's own evaluation.
* **Device**: ``cpu`` unless ``--policy-device`` says otherwise.
* **Determinism**: torch's global generator is seeded from the episode id at every
  reset (Diffusion Policy draws its noise from it), so a rerun gives the same bytes.
"""

from __future__ import annotations

import hashlib
import json
import re
import zlib
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Any

from catalog.loader.lerobot_names import ACTION_KEY, ENV_KEY, IMAGE_KEY, STATE_KEY
from pipeline.policies.base import Task
from pipeline.policies.lerobot_adapter import LeRobotAdapter
from schemas.errors import PolicyError, SpecError
from schemas.names import shorten

PREFIX = "lerobot:"
PREPROCESSOR = "policy_preprocessor.json"
POSTPROCESSOR = "policy_postprocessor.json"
DEVICE = re.compile(r"^(cpu|mps|cuda(:\d+)?)$")
STATE_SIZE = 21
ACTION_SIZE = 18
INSTALL = "pip install 'lerobot>=0.4' (see docs/guides/export-lerobot.md)"
PRIVILEGED = {ENV_KEY: "the object's true pose, which the closed loop never shows a policy; "
              "export without it (the default) and train again"}


def checkpoint_folder(path: str) -> Path:
    """The ``pretrained_model`` folder ``path`` names (itself, or inside a training output)."""
    try:
        root = Path(path).expanduser()
    except RuntimeError:  # ~name of no such user
        raise PolicyError(f"{shorten(path)}: no such checkpoint folder (its ~user is not a user here)") from None
    for candidate in (root, root / "pretrained_model", root / "checkpoints" / "last" / "pretrained_model"):
        if (candidate / "config.json").is_file():
            return candidate.resolve()
    if not root.exists():
        raise PolicyError(f"{shorten(path)}: no such checkpoint folder")
    raise PolicyError(f"{shorten(path)}: not a LeRobot checkpoint (no config.json in it, its pretrained_model/ "
                      "or checkpoints/last/pretrained_model/)")


@dataclass(frozen=True)
class Checkpoint:
    """What a checkpoint's ``config.json`` says Dyana must give it: its folder, policy type,
    the key and (height, width) of its image input (None: no image), whether it takes the
    state, and whether it keeps its normalisation in saved processors (LeRobot >= 0.4)."""

    folder: str
    policy_type: str
    image_key: str | None
    image_size: tuple[int, int] | None
    state: bool
    processors: bool

    def __post_init__(self) -> None:
        if (self.image_key is None) != (self.image_size is None):
            raise SpecError("Checkpoint: image_key and image_size go together")
        if self.image_key is None and not self.state:
            raise PolicyError(f"{shorten(self.folder)}: the policy takes neither an image nor {STATE_KEY}")

    @property
    def model_sha256(self) -> str:
        digest = hashlib.sha256()
        with open(Path(self.folder) / "model.safetensors", "rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
        return digest.hexdigest()

    def inputs(self) -> dict[str, str]:
        """Dyana's batch key -> the policy's input key."""
        out = {STATE_KEY: STATE_KEY} if self.state else {}
        if self.image_key is not None:
            out[IMAGE_KEY] = self.image_key
        return out


def _shape(name: str, key: str, feature: Any) -> list[int]:
    shape = feature.get("shape") if isinstance(feature, dict) else None
    if not isinstance(shape, list) or not all(isinstance(n, int) and not isinstance(n, bool) for n in shape):
        raise PolicyError(f"{name}: config.json: feature {shorten(key)} has no integer shape")
    return shape


def read_checkpoint(path: str) -> Checkpoint:
    """The checkpoint at ``path``, checked against what Dyana gives a non-privileged policy
    (PolicyError naming the first input it cannot give)."""
    folder = checkpoint_folder(path)
    name = shorten(str(folder))
    try:
        config = json.loads((folder / "config.json").read_text())
    except (OSError, ValueError) as exc:
        raise PolicyError(f"{name}/config.json: unreadable ({shorten(str(exc))})") from None
    except RecursionError:
        raise PolicyError(f"{name}/config.json: unreadable (nested too deeply)") from None
    if not (folder / "model.safetensors").is_file():
        raise PolicyError(f"{name}: no model.safetensors beside config.json")
    inputs, outputs = (config.get(k) if isinstance(config, dict) else None for k in ("input_features", "output_features"))
    if not isinstance(inputs, dict) or not isinstance(outputs, dict) or not isinstance(config.get("type"), str):
        raise PolicyError(f"{name}/config.json: no type, input_features or output_features (not a LeRobot policy config)")
    action = outputs.get(ACTION_KEY)
    if action is None or _shape(name, ACTION_KEY, action) != [ACTION_SIZE] or set(outputs) != {ACTION_KEY}:
        raise PolicyError(f"{name}: the policy outputs {shorten(json.dumps(outputs, sort_keys=True))}; "
                          f"Dyana takes one {ACTION_KEY!r} of {ACTION_SIZE} (palm xyz, 15 joints)")
    image_key: str | None = None
    image_size: tuple[int, int] | None = None
    state = False
    for key, feature in inputs.items():
        kind = feature.get("type") if isinstance(feature, dict) else None
        shape = _shape(name, key, feature)
        if kind == "VISUAL" and image_key is None and len(shape) == 3 and shape[0] == 3:
            image_key, image_size = key, (shape[1], shape[2])
        elif kind == "VISUAL" and image_key is not None:
            raise PolicyError(f"{name}: the policy takes a second image {shorten(key)} (besides {image_key}); "
                              "Dyana gives one camera")
        elif key == STATE_KEY and shape == [STATE_SIZE]:
            state = True
        else:
            why = PRIVILEGED.get(key, f"a {kind} input of shape {shape} that Dyana does not give a policy "
                                      f"(it gives one image and {STATE_KEY} ({STATE_SIZE}))")
            raise PolicyError(f"{name}: the policy takes {shorten(key)}: {why}")
    return Checkpoint(str(folder), config["type"], image_key, image_size, state, (folder / PREPROCESSOR).is_file())


def check_device(device: Any) -> str:
    if not isinstance(device, str) or not DEVICE.match(device):
        raise SpecError(f"--policy-device must be cpu, cuda, cuda:N or mps, got {shorten(repr(device))}")
    return device


def lerobot_version() -> str:
    try:
        return metadata.version("lerobot")
    except metadata.PackageNotFoundError:
        return "unknown"


def configure(ref: str, config: dict[str, Any] | None) -> dict[str, Any]:
    """The kind's configuration (the run's manifest records it): the checkpoint, its model's
    sha256, its policy type and normalisation style, the device. Checks the checkpoint's
    features before anything is loaded."""
    if config is not None and set(config) - {"device"}:
        raise SpecError(f"{shorten(ref)}: a LeRobot checkpoint takes --policy-device only")
    device = check_device((config or {}).get("device", "cpu"))
    checkpoint = read_checkpoint(ref[len(PREFIX):])
    return {"checkpoint": checkpoint.folder, "model_sha256": checkpoint.model_sha256, "type": checkpoint.policy_type,
            "normalisation": "processors" if checkpoint.processors else "model", "device": device}


class ProcessedPolicy:
    """A loaded LeRobot policy behind its checkpoint's input keys and (LeRobot >= 0.4) its
    saved pre- and post-processors: ``reset()`` and ``select_action(batch)`` over Dyana's keys."""

    def __init__(self, policy: Any, inputs: dict[str, str], preprocessor: Any = None, postprocessor: Any = None) -> None:
        self.policy = policy
        self.inputs = inputs
        self.preprocessor = preprocessor
        self.postprocessor = postprocessor

    def reset(self) -> None:
        self.policy.reset()
        for step in (self.preprocessor, self.postprocessor):
            if callable(getattr(step, "reset", None)):
                step.reset()

    def select_action(self, batch: dict[str, Any]) -> Any:
        keyed = {self.inputs[k]: v for k, v in batch.items() if k in self.inputs}
        keyed["task"] = batch["task"]
        if self.preprocessor is not None:
            keyed = self.preprocessor(keyed)
        action = self.policy.select_action(keyed)
        return action if self.postprocessor is None else self.postprocessor(action)


class CheckpointPolicy(LeRobotAdapter):
    """:class:`LeRobotAdapter` that seeds torch from the episode id at every reset."""

    def reset(self, task: Task) -> None:
        self.torch.manual_seed(zlib.crc32(str(task.get("episode_id", task.get("text", ""))).encode()))
        super().reset(task)


def load(checkpoint: Checkpoint, device: str) -> ProcessedPolicy:
    """The checkpoint's policy (and processors) with the installed lerobot, on ``device``."""
    try:
        import lerobot.policies.factory as factory
        from lerobot.configs.policies import PreTrainedConfig
    except ImportError as exc:
        raise PolicyError(f"lerobot:PATH needs LeRobot in this Python ({shorten(str(exc))}): {INSTALL}") from None
    version = lerobot_version()
    has_processors = hasattr(factory, "make_pre_post_processors")
    if checkpoint.processors and not has_processors:
        raise PolicyError(f"{shorten(checkpoint.folder)}: saved by LeRobot >= 0.4 ({PREPROCESSOR}), but lerobot "
                          f"{version} keeps normalisation inside the model: {INSTALL}")
    if not checkpoint.processors and has_processors:
        raise PolicyError(f"{shorten(checkpoint.folder)}: a LeRobot 0.3 checkpoint (no {PREPROCESSOR}) and lerobot "
                          f"{version} normalises in saved processors: run it with lerobot 0.3.x, or migrate it with "
                          "python -m lerobot.processor.migrate_policy_normalization")
    config = PreTrainedConfig.from_pretrained(checkpoint.folder)
    config.device = device
    if hasattr(config, "pretrained_backbone_weights"):
        config.pretrained_backbone_weights = None  # the weights come from model.safetensors: no download
    policy = factory.get_policy_class(config.type).from_pretrained(checkpoint.folder, config=config)
    policy.eval()
    if not checkpoint.processors:
        return ProcessedPolicy(policy, checkpoint.inputs())
    preprocessor, postprocessor = factory.make_pre_post_processors(
        policy_cfg=config, pretrained_path=checkpoint.folder,
        preprocessor_overrides={"device_processor": {"device": device}})
    return ProcessedPolicy(policy, checkpoint.inputs(), preprocessor, postprocessor)


def policy_name(config: dict[str, Any]) -> str:
    """The name a run records for a checkpoint's policy, from its configuration (:func:`configure`): type and model hash."""
    return f"lerobot-{config['type']}-{config['model_sha256'][:8]}"


def make(ref: str, config: dict[str, Any] | None) -> CheckpointPolicy:
    """The policy of ``lerobot:PATH`` (``config`` as :func:`configure` made it, or None)."""
    config = config if config is not None and "checkpoint" in config else configure(ref, config)
    checkpoint = read_checkpoint(config["checkpoint"])
    sha256 = checkpoint.model_sha256
    if sha256 != config.get("model_sha256", sha256):
        raise PolicyError(f"{shorten(checkpoint.folder)}/model.safetensors changed since the run started")
    loaded = load(checkpoint, config["device"])
    name = policy_name({"type": checkpoint.policy_type, "model_sha256": sha256})
    return CheckpointPolicy(loaded, name, device=config["device"], image_size=checkpoint.image_size)
