"""Held-out splits drawn from a private seed (generators.heldout): the public slice's
cells from draws nobody without the secret can make, and a manifest record that holds
only the secret's hash."""

from __future__ import annotations

import numpy as np
import pytest

from generators.heldout import (
    HOW_TO_MAKE,
    PRIVATE_SEED,
    SCHEME,
    check_secret,
    derive,
    matching,
    private_specs,
)
from generators.recipe import slice_specs
from schemas.errors import SpecError

SECRET = "5b0e1c9d27f84a6e93c1d0b8f2a47e65"
OTHER = "c3a9f1e07d2b4c68a5e19f30b7d64c28"


def test_a_private_split_has_the_public_cells_and_is_deterministic():
    public = list(slice_specs("test-1k", 18))
    seed = derive(SECRET, "test-1k")
    private = private_specs(seed, 0, 18)
    assert private_specs(derive(SECRET, "test-1k"), 0, 18) == private
    assert [(s.motion_type, s.intercept_setting) for s in private] == [(s.motion_type, s.intercept_setting) for s in public]
    assert [s.episode_id for s in private] == [s.episode_id for s in public]  # ids say nothing of the seed
    assert {s.seed for s in private} == {PRIVATE_SEED}
    assert all(a.motion != b.motion for a, b in zip(private, public))
    assert private_specs(derive(OTHER, "test-1k"), 0, 18) != private
    complex_private = private_specs(derive(SECRET, "test-complex"), 0, 6)
    complex_public = list(slice_specs("test-complex", 6))
    assert [s.motion_type for s in complex_private] == [s.motion_type for s in complex_public]
    assert all(a.motion != b.motion for a, b in zip(complex_private, complex_public))



@pytest.mark.parametrize("secret", ["", "0123456789abcde", "abababababababababab", "tab\tinside-0123456789", "x" * 2000])
def test_weak_or_odd_secrets_are_refused_with_the_rule_and_never_echoed(secret):
    with pytest.raises(SpecError) as caught:
        check_secret(secret)
    assert HOW_TO_MAKE in str(caught.value)
    assert len(secret) < 8 or secret not in str(caught.value)


def test_the_record_holds_the_hash_only_and_each_slice_has_its_own_salt():
    seed = derive(SECRET, "test-1k")
    record = seed.record()
    assert record["salt"] == "dyana/test-seed/v1/test-1k" and len(record["hash"]) == 64
    assert SECRET not in str(record) and str(seed.generator_seed) not in str(record) and "generator_seed" not in repr(seed)
    assert derive(SECRET, "test-complex").digest != seed.digest
    assert derive(SECRET, "test-complex").generator_seed != seed.generator_seed
    assert matching(SECRET, record, "here").generator_seed == seed.generator_seed
    with pytest.raises(SpecError, match="here: the test seed given does not match"):
        matching(OTHER, record, "here")
    with pytest.raises(SpecError, match="another key derivation"):
        matching(SECRET, {**record, "n": 1024}, "here")


def test_training_slices_refuse_a_private_seed():
    with pytest.raises(SpecError, match="assigned, not drawn"):
        derive(SECRET, "circular-slow")


def _grid_values(spec) -> list[tuple[str, float, np.ndarray]]:
    """(axis, the spec's value, the public grid's values) of each continuous axis of its motion."""
    from generators.grids import GRID_AXES

    token = spec.motion.base.tokens[0]
    values = {"linear": {"start_x": lambda t: t.start[0], "start_z": lambda t: t.start[1], "direction": lambda t: t.direction,
                         "speed": lambda t: t.speed},
              "circular": {"centre_x": lambda t: t.centre[0], "centre_z": lambda t: t.centre[1], "radius": lambda t: t.radius,
                           "angular_velocity": lambda t: t.angular_velocity, "start_angle": lambda t: t.start_angle},
              "harmonic": {"centre_x": lambda t: t.centre[0], "centre_z": lambda t: t.centre[1], "axis": lambda t: t.axis,
                           "amplitude": lambda t: t.amplitude, "frequency": lambda t: t.frequency,
                           "phase": lambda t: t.phase}}[spec.motion_type]
    return [(axis, get(token), GRID_AXES[spec.motion_type][axis]) for axis, get in values.items()]


def test_private_motions_are_drawn_between_the_public_grid_values_and_stay_feasible():
    from generators.grids import OBJECT_NAMES, OBJECT_RADII, OBJECT_SIZES, OBJECT_TOPS, derived_columns, feasible
    from generators.heldout import motion_axes as heldout_axes

    public = list(slice_specs("test-1k", 45))
    private = private_specs(derive(SECRET, "test-1k"), 0, 45)
    for spec in public:  # the public draws sit on the grid: the check below can fail
        assert all(np.isclose(grid, value, atol=1e-6).any() for _, value, grid in _grid_values(spec))
    for spec in private:  # every continuous value of every private motion is off the grid, so in no pool row
        for axis, value, grid in _grid_values(spec):
            assert not np.isclose(grid, value, atol=1e-6).any(), (spec.episode_id, axis, value)
    for spec in private:  # the object stays in the workspace and in view all along, as a public draw's does
        token = spec.motion.base.tokens[0]
        motion_type, axes = heldout_axes(token)
        cols = derived_columns(motion_type, {name: np.array([value]) for name, value in axes.items()})
        obj = OBJECT_NAMES.index(spec.object)
        size = int(np.argmin(np.abs(OBJECT_SIZES[obj] - spec.object_size)))
        assert feasible(motion_type, cols, np.array([token.duration]), OBJECT_RADII[obj:obj + 1, size],
                        OBJECT_TOPS[obj:obj + 1, size])[0]
    assert {s.motion_type for s in private} == {"linear", "circular", "harmonic"}


def test_a_run_drawn_by_the_first_scheme_replays_from_public_rows():
    record = derive(SECRET, "test-1k").record()
    assert record["scheme"] == SCHEME == 2
    old = matching(SECRET, {k: v for k, v in record.items() if k != "scheme"}, "here")  # made before scheme 2
    assert old.scheme == 1
    first = private_specs(old, 0, 9)
    assert all(np.isclose(grid, value, atol=1e-6).any() for spec in first for _, value, grid in _grid_values(spec))
    assert first != private_specs(derive(SECRET, "test-1k"), 0, 9)
    with pytest.raises(SpecError, match="scheme 7, which this code does not know"):
        matching(SECRET, {**record, "scheme": 7}, "here")
