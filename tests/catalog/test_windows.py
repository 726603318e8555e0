"""Window arithmetic: histories and horizons stay inside their episode, padded and flagged."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from catalog.loader.windows import (
    episode_starts,
    history_span,
    history_window,
    horizon_span,
    horizon_window,
    locate,
    window,
)


def test_history_pads_at_the_episode_start_oldest_first():
    frames, is_pad = history_window(1, 10, 3)
    assert frames.tolist() == [0, 0, 0, 1]
    assert is_pad.tolist() == [True, True, False, False]
    frames, is_pad = history_window(7, 10, 3)
    assert frames.tolist() == [4, 5, 6, 7]
    assert not is_pad.any()


def test_horizon_pads_at_the_episode_end_with_the_last_frame():
    frames, is_pad = horizon_window(8, 10, 4)
    assert frames.tolist() == [8, 9, 9, 9]
    assert is_pad.tolist() == [False, False, True, True]
    frames, is_pad = horizon_window(0, 10, 1)
    assert frames.tolist() == [0] and is_pad.tolist() == [False]


def test_a_window_longer_than_the_episode_pads_both_ends():
    frames, is_pad = window(1, 3, -2, 6)
    assert frames.tolist() == [0, 0, 1, 2, 2, 2]
    assert is_pad.tolist() == [True, False, False, False, True, True]


def test_bad_arguments_are_refused():
    with pytest.raises(IndexError):
        history_window(5, 5, 1)
    with pytest.raises(IndexError):
        horizon_window(-1, 5, 1)
    with pytest.raises(ValueError):
        window(0, 5, 0, 0)
    with pytest.raises(ValueError):
        episode_starts([3, -1])


@given(
    n=st.integers(1, 60),
    data=st.data(),
    history=st.integers(0, 20),
    horizon=st.integers(1, 20),
)
def test_windows_match_brute_force(n, data, history, horizon):
    f = data.draw(st.integers(0, n - 1))
    frames, is_pad = history_window(f, n, history)
    assert frames.dtype == np.int64 and is_pad.dtype == bool
    for j, wanted in enumerate(range(f - history, f + 1)):
        assert is_pad[j] == (wanted < 0)
        assert frames[j] == max(wanted, 0)
    assert frames[-1] == f and not is_pad[-1]
    frames, is_pad = horizon_window(f, n, horizon)
    for j, wanted in enumerate(range(f, f + horizon)):
        assert is_pad[j] == (wanted >= n)
        assert frames[j] == min(wanted, n - 1)
    assert frames[0] == f and not is_pad[0]
    assert np.all((frames >= 0) & (frames < n))


@given(n=st.integers(1, 60), data=st.data(), history=st.integers(0, 20), horizon=st.integers(1, 20))
def test_spans_describe_the_windows(n, data, history, horizon):
    f = data.draw(st.integers(0, n - 1))
    pad, start = history_span(f, history)
    frames, is_pad = history_window(f, n, history)
    assert frames.tolist() == [0] * pad + list(range(start, f + 1))
    assert is_pad.tolist() == [True] * pad + [False] * (f + 1 - start)
    stop, pad = horizon_span(f, n, horizon)
    frames, is_pad = horizon_window(f, n, horizon)
    assert frames.tolist() == list(range(f, stop)) + [n - 1] * pad
    assert is_pad.tolist() == [False] * (stop - f) + [True] * pad


@given(st.lists(st.integers(0, 6), min_size=1, max_size=12))
def test_locate_inverts_concatenation_and_skips_empty_episodes(lengths):
    starts = episode_starts(lengths)
    total = sum(lengths)
    expected = [(k, f) for k, n in enumerate(lengths) for f in range(n)]
    assert [locate(i, starts, total) for i in range(total)] == expected
    for bad in (-1, total):
        with pytest.raises(IndexError):
            locate(bad, starts, total)
