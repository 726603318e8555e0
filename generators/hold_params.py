"""The hold test's constants (:mod:`generators.hold`), each with its reason; the long form
is ``docs/concepts/grasp-hold.md``. Scene units: 1 unit = 10 cm, kg, s."""

from __future__ import annotations

from types import MappingProxyType

from schemas.errors import SpecError
from schemas.names import shorten
from schemas.objects import object_category

#: Physics steps per second: pybullet's default 240 Hz, 12 steps per 20 FPS frame (at
#: 120 Hz, 5 of 25 placements that hold at 240 Hz drop: the fingers' contacts need it).
STEPS_PER_SECOND = 240
#: Solver iterations per step, fixed: 20, not pybullet's default 50, cuts a test's CPU
#: time by a third (121 -> 81 ms measured) at 240 Hz.
SOLVER_ITERATIONS = 20
#: 9.81 m/s^2 in units/s^2.
GRAVITY = 98.1

#: The palm rises 2 units (20 cm) over 0.5 s, then holds still 0.5 s. The lift is 4x the
#: slip tolerance, so a dropped object ends far outside it; 0.5 s keeps the peak upward
#: acceleration at 5.77 * 2 / 0.25 = 46 units/s^2 (0.47 g); 0.5 s of stillness lets an
#: object that is sliding out fall at least 12 units (g t^2 / 2), past the tolerance.
LIFT_HEIGHT = 2.0
LIFT_SECONDS = 0.5
HOLD_SECONDS = 0.5
#: Held: the object's centre ends within 0.5 units (5 cm) of where it started in the
#: palm's frame; an object settling in the fingers moves less, a dropped one ~LIFT_HEIGHT.
SLIP_TOLERANCE = 0.5

#: A hand that starts more than 0.05 units (5 mm) inside the object holds nothing: no real
#: hand gets there, and pybullet's push-out would jam the object between palm and fingers
#: (a blind hand that closed with its palm 0.14 deep in a mug "held" it). The ground
#: truth starts at 0 for spheres, upright cylinders and boxes; in lying cylinders its
#: fingers start up to 0.41 deep (its grasp is sized for the axis across the palm; the
#: axis follows the path).
PENETRATION_TOLERANCE = 0.05

#: The palm's mass (the renderer's URDF) and each finger segment's (kg).
PALM_MASS = 0.4
SEGMENT_MASS = 0.02
#: Most force the palm's drive may apply (0.1 N units: 3000 = 300 N), far above the
#: weights it carries, so the palm follows its path.
HAND_FORCE = 3000.0
#: Each finger joint is driven to its angle plus 0.2 rad with at most 0.5 N m (50 in
#: kg unit^2/s^2): a finger that closed on the object presses on it; 0.2 rad exceeds the
#: ground truth's remaining closure at its first closed frame (at most 0.09 rad).
GRIP_OVERSHOOT = 0.2
GRIP_TORQUE = 50.0

#: Coulomb friction coefficients; pybullet multiplies the two bodies' values. Skin 1.0;
#: the table 0.5 (its contact with an object is 0.5 x the object's).
HAND_FRICTION = 1.0
TABLE_FRICTION = 0.5
#: Each category's material against skin, and its mass at the nominal size (kg); the mass
#: scales with the size cubed (same density).
_OBJECTS = MappingProxyType({
    "tennis_ball": (0.9, 0.058),  # felt; ITF 56-59.4 g
    "baseball": (0.8, 0.145),  # leather; MLB 142-149 g
    "orange": (0.7, 0.15),  # peel; a medium 8 cm orange
    "soda_can": (0.5, 0.37),  # aluminium; a full 355 ml can
    "water_bottle": (0.5, 0.52),  # PET; a full 500 ml bottle
    "paper_roll": (0.8, 0.12),  # paper; a toilet roll of 11 cm
    "mug": (0.6, 0.35),  # glazed ceramic
    "cup": (0.6, 0.20),  # ceramic cup
    "cracker_box": (0.7, 0.15),  # cardboard, 16 x 6 x 6 cm of crackers
    "sugar_box": (0.7, 0.17),  # cardboard, 9 x 5 x 4.4 cm of sugar
    "toy_cube": (0.7, 0.13),  # wood, 6 cm
})


def _entry(name: str) -> tuple[float, float]:
    object_category(name)
    try:
        return _OBJECTS[name]
    except KeyError:
        raise SpecError(f"the hold test has no material for object {shorten(repr(name))}") from None


def object_friction(name: str) -> float:
    """Friction coefficient of ``name``'s surface."""
    return _entry(name)[0]


def object_mass(name: str, size: float) -> float:
    """Mass (kg) of ``name`` at width ``size``: its nominal mass times (size / nominal)^3."""
    return _entry(name)[1] * (size / object_category(name).nominal_size) ** 3
