import dataclasses

import pytest

from schemas.errors import DyanaError, SliceError, SpecError
from schemas.scene import INTERCEPT_SECONDS, MOTION_TYPES
from schemas.slices import (
    ATOMIC_SLICES,
    FIGURE4_EPISODES,
    SLICES,
    TEST_SEED,
    SliceDef,
    get_slice,
    slice_names,
)


def test_registry_lists_nine_atomic_slices_then_test_and_union():
    nine = [f"{m}-{s}" for m in MOTION_TYPES for s in INTERCEPT_SECONDS]
    assert list(ATOMIC_SLICES) == nine
    harder = [f"{f}-{s}" for f in ("projectile", "obstacle", "irregular") for s in INTERCEPT_SECONDS]
    assert list(slice_names()) == nine + ["test-1k", "dyana-12m"] + harder + ["test-irregular", "test-complex"]
    for name in harder:
        definition = get_slice(name)
        assert definition.generator == name.split("-")[0] == definition.motion_type and not definition.atomic
        assert definition.episodes == 600
    assert get_slice("test-complex").generator == "complex" and get_slice("test-complex").episodes == 300
    for name in nine:
        motion_type, setting = name.split("-")
        definition = get_slice(name)
        assert (definition.motion_type, definition.intercept_setting) == (motion_type, setting)
        assert definition.atomic and not definition.union


def test_figure4_episode_counts_split_evenly_over_settings():
    assert FIGURE4_EPISODES == {"linear": 44_546, "circular": 89_709, "harmonic": 50_463}
    for motion_type, total in FIGURE4_EPISODES.items():
        counts = [get_slice(f"{motion_type}-{s}").episodes for s in INTERCEPT_SECONDS]
        assert sum(counts) == total
        assert max(counts) - min(counts) <= 1
    assert [get_slice(f"linear-{s}").episodes for s in INTERCEPT_SECONDS] == [14_849, 14_849, 14_848]


def test_test_1k_and_dyana_12m():
    test = get_slice("test-1k")
    assert test.episodes == 1_000 and test.motion_type is None and test.intercept_setting is None
    assert not test.union and not test.atomic
    union = get_slice("dyana-12m")
    assert union.parts == ATOMIC_SLICES
    assert union.episodes == 184_718 == sum(get_slice(n).episodes for n in ATOMIC_SLICES)


def test_seeds_are_distinct_and_test_seed_is_its_own():
    seeds = [get_slice(n).seed for n in ATOMIC_SLICES]
    assert len(set(seeds)) == 9
    assert get_slice("test-1k").seed == TEST_SEED
    assert TEST_SEED not in seeds
    assert get_slice("linear-fast").seed == 1  # what every linear-fast catalog.json records


def test_unknown_slice_names_value_and_known_slices():
    with pytest.raises(SliceError) as info:
        get_slice("linear-sloww")
    message = str(info.value)
    assert "unknown slice 'linear-sloww' (did you mean 'linear-slow'?)" in message
    assert all(name in message for name in SLICES)
    assert "\n" not in message and not message.startswith('"')
    assert isinstance(info.value, DyanaError) and isinstance(info.value, KeyError)
    with pytest.raises(SliceError):
        get_slice(None)


@pytest.mark.parametrize(
    "kwargs, needle",
    [
        (dict(motion_type="spiral", intercept_setting="fast"), "motion_type"),
        (dict(motion_type="linear", intercept_setting="slowest"), "intercept_setting"),
        (dict(motion_type="linear", intercept_setting=None), "both"),
        (dict(episodes=0), "episodes"),
        (dict(episodes=True), "episodes"),
        (dict(seed=-1), "seed"),
        (dict(name=""), "name"),
        (dict(motion_type="linear", intercept_setting="fast", parts=("a",)), "union"),
    ],
)
def test_slicedef_validates(kwargs, needle):
    base = dict(name="x", motion_type=None, intercept_setting=None, episodes=1, seed=0)
    base.update(kwargs)
    with pytest.raises(SpecError, match=needle):
        SliceDef(**base)


def test_slicedef_is_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        get_slice("linear-fast").episodes = 3
