"""Scene conventions shared by every stage (the data contract, ``docs/concepts/data-contract.md``).

World frame: X right, Y up, Z forward (away from the camera); the table top is Y = 0.
1 unit = 10 cm. Episodes run at :data:`schemas.versions.FPS` frames per second.
"""

from __future__ import annotations

from fractions import Fraction

#: Fixed egocentric camera, looking forward and down at the workspace.
CAMERA_EYE = (0.0, 9.0, -3.0)
CAMERA_TARGET = (0.0, 0.0, 4.5)
CAMERA_UP = (0.0, 1.0, 0.0)
CAMERA_FOV_DEG = 60.0
CAMERA_NEAR = 0.5
CAMERA_FAR = 40.0
DEFAULT_RESOLUTION = 224

#: Where an object's centre may be, on the table, during a whole episode.
WORKSPACE_X = (-3.5, 3.5)
WORKSPACE_Z = (1.5, 7.5)
#: The table's top, larger than the workspace.
TABLE_X = (-6.0, 6.0)
TABLE_Z = (-1.0, 10.0)

#: The palm's rest pose (x, y, z, roll, pitch, yaw): palm down at the bottom edge of the
#: view, fingers pointing into the image, as an egocentric hand waits. The whole resting
#: hand projects below every point of the workspace an object can occupy, so it never
#: hides the target while the model observes it (generators.visibility); its height is
#: the highest hover point of any recipe object, so approaches only ever descend.
PALM_REST = (0.0, 1.65, -1.8, 0.0, 0.0, 0.0)
#: Where the palm may go (x, y, z ranges): above the table, up to 6 units high, from
#: behind the rest pose (at the view's bottom edge) to the table's far edge. The closed
#: loop clamps every action into it; the ground truth's approach to a flying ball stays in it.
PALM_BOX = (TABLE_X, (0.0, 6.0), (min(TABLE_Z[0], PALM_REST[2] - 1.0), TABLE_Z[1]))
#: The box's lower and upper corners (x, y, z).
PALM_LOW = tuple(r[0] for r in PALM_BOX)
PALM_HIGH = tuple(r[1] for r in PALM_BOX)
#: Share of the object's silhouette that must be in the image and unhidden in every
#: observe frame (the observe-before-act protocol shows the model the motion).
MIN_OBSERVE_VISIBLE = 0.5
#: Palm centre height above the object's top while hovering and grasping.
PALM_HOVER = 0.35

#: Localization tolerance in the XZ plane (paper A.5) and the grasp ratio.
LOC_TOLERANCE = 0.3
GRASP_RATIO = 0.8
#: Contact tolerance of Dyana's contact-grounded grasp: a fingertip within it of the object's
#: surface (paper A.8 has a tolerance eps_gras to the object's centre, without a value).
#: 0.15 units = 1.5 cm: the ground truth's closest fingertip at its grasp frames is 0.070
#: units at the median and 0.085 at worst (420 recipe episodes), and its minimum E_gra is
#: 0.057, so the ground truth passes with margin while a fist closed
#: beside the object does not.
GRASP_CONTACT_TOLERANCE = 0.15

#: Interception settings: seconds from the first acting frame to arrival.
INTERCEPT_SECONDS = {"fast": 0.5, "medium": 1.0, "slow": 1.5}
#: A closed-loop policy may act for ceil(HORIZON_FACTOR x the ground truth's acting frames).
HORIZON_FACTOR = Fraction(6, 5)

#: Frames to close the fingers after arrival, then frames of hold.
GRASP_FRAMES = 6
HOLD_FRAMES = 4

PHASES = ("observe", "approach", "grasp", "hold")
MOTION_TYPES = ("linear", "circular", "harmonic")
#: Harder settings of the paper's appendix A.11 (not part of Dyana-12M or test-1k).
COMPLEX_MOTION_TYPES = ("projectile", "obstacle", "irregular")
ROLLOUT_FORMATS = ("observe-before-act", "direct-act")
HANDS = ("right", "left")
