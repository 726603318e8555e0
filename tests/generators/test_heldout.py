"""Held-out splits drawn from a private seed (generators.heldout): the public slice's
cells from draws nobody without the secret can make, and a manifest record that holds
only the secret's hash."""

from __future__ import annotations

import pytest

from generators.heldout import (
    HOW_TO_MAKE,
    PRIVATE_SEED,
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
