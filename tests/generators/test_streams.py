"""generators.streams: many episodes' first doubles at once, equal to numpy's generators."""

from __future__ import annotations

import numpy as np
import pytest

from generators.recipe import N_DRAWS, episode_table
from generators.streams import MAX_VECTOR_INDEX, stream_doubles
from schemas.errors import SpecError


def numpy_doubles(seed: int, index: int, first: int, count: int) -> np.ndarray:
    generator = np.random.Generator(np.random.PCG64(np.random.SeedSequence([seed, index])))
    return generator.random(first + count)[first:]


@pytest.mark.parametrize("seed", [0, 1, 20250611, 2**32 - 1, 2**32, 2**63 + 7, 2**96 + 5])
def test_every_double_equals_numpys_generator(seed: int) -> None:
    rng = np.random.default_rng(seed % 1000)
    indices = np.concatenate([np.arange(40), rng.integers(0, MAX_VECTOR_INDEX + 1, 40),
                              [MAX_VECTOR_INDEX, MAX_VECTOR_INDEX + 1, 2**40 + 3]])
    for first, count in [(0, N_DRAWS), (N_DRAWS, N_DRAWS), (5 * N_DRAWS, 3), (2, 0)]:
        got = stream_doubles(seed, indices, first, count)
        assert got.shape == (len(indices), count)
        for row, index in enumerate(indices):
            assert np.array_equal(got[row], numpy_doubles(seed, int(index), first, count)), (seed, index, first)


def test_unsigned_and_signed_indices_agree() -> None:
    signed = np.arange(100, dtype=np.int64)
    assert np.array_equal(stream_doubles(3, signed, 0, 4), stream_doubles(3, signed.astype(np.uint32), 0, 4))


def test_the_recipe_draws_from_each_episodes_own_stream() -> None:
    """An episode's choices do not depend on which other episodes are drawn with it."""
    table = episode_table("circular-fast", 300).columns
    for i in (0, 17, 299):
        alone = episode_table("circular-fast", i + 1).columns
        assert all(np.array_equal(alone[k][i], table[k][i]) for k in table), i


@pytest.mark.parametrize(
    "args, named",
    [
        ((-1, np.arange(3), 0, 1), "seed"),
        ((True, np.arange(3), 0, 1), "seed"),
        ((1, np.arange(3), -1, 1), "first"),
        ((1, np.arange(3), 0, 1.5), "count"),
        ((1, np.array([1, -2]), 0, 1), "indices"),
        ((1, np.array([[1, 2]]), 0, 1), "indices"),
        ((1, np.array([0.5]), 0, 1), "indices"),
    ],
)
def test_bad_arguments_are_one_error_naming_them(args, named: str) -> None:
    with pytest.raises(SpecError, match=named):
        stream_doubles(*args)
