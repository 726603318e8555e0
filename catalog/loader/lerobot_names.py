"""LeRobot's names for Dyana's data: the one mapping that the export
(:mod:`catalog.export.layout`), the keyed reader (:mod:`catalog.loader.lerobot_keys`) and the closed
loop's LeRobot policies (:mod:`pipeline.policies.lerobot_adapter`,
:mod:`pipeline.policies.lerobot_checkpoint`, :mod:`pipeline.policies.chunk_cnn`) all use.

=================================  ======================================================
LeRobot feature                    Dyana source
=================================  ======================================================
``observation.images.ego``         ``image`` (the egocentric frame)
``observation.state`` (21)         ``palm_pose`` (6: xyz, roll, pitch, yaw) then
                                   ``joint_angles`` (15)
``observation.environment_state``  ``object_pose`` (7: xyz, quaternion x, y, z, w); privileged
                                   (the closed loop never shows it to a policy)
``action`` (18)                    ``action`` (palm xyz target, 15 joint targets)
``<feature>_is_pad``               the padded slots of a history or an action horizon
``timestamp``, ``frame_index``,    LeRobot's index features
``episode_index``, ``index``,
``task_index``
=================================  ======================================================

Only names live here (no numpy), so that importing them costs nothing.
"""

from __future__ import annotations

IMAGE_KEY = "observation.images.ego"
STATE_KEY = "observation.state"
ENV_KEY = "observation.environment_state"
ACTION_KEY = "action"
#: LeRobot's image features are ``observation.images.<camera>`` (an environment's ``pixels[camera]``
#: in its evaluation); Dyana's one camera is :data:`CAMERA`.
IMAGES_PREFIX = "observation.images."
CAMERA = IMAGE_KEY.removeprefix(IMAGES_PREFIX)
#: The Dyana column the image feature holds.
IMAGE_SOURCE = "image"
#: Each vector feature -> the Dyana frames columns it concatenates, in order.
VECTOR_SOURCES = {
    STATE_KEY: ("palm_pose", "joint_angles"),
    ENV_KEY: ("object_pose",),
    ACTION_KEY: ("action",),
}
#: LeRobot's index features (``timestamp`` float32, the others int64).
INDEX_FEATURES = ("timestamp", "frame_index", "episode_index", "index", "task_index")
PAD_SUFFIX = "_is_pad"


def pad_key(key: str) -> str:
    """The flags of ``key``'s padded history or horizon slots (``action`` -> ``action_is_pad``)."""
    return key + PAD_SUFFIX
