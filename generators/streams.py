"""The first doubles of many episodes' streams at once, bit for bit numpy's.

Episode ``i`` of a slice draws from ``Generator(PCG64(SeedSequence([seed, i])))``.
Building that generator costs about 30 µs (the seed hashing and PCG64's set-up run per
call), which is most of the time of a whole slice's choices (``catalog list`` draws
every episode of the recipe). :func:`stream_doubles` computes the same doubles for a
whole array of episode indices with numpy arrays: numpy's ``SeedSequence`` hashing
(pool of 4 words, :func:`_pool_words`), PCG64's seeding from its 4 64-bit words and its
XSL-RR output (:func:`_pcg64_doubles`), in 128-bit arithmetic on four 32-bit limbs.
These algorithms are numpy's documented, stable streams (NEP 19); ``tests/generators/
test_streams.py`` checks every value against numpy's own generators.
"""

from __future__ import annotations

import numpy as np

from schemas.errors import SpecError
from schemas.names import shorten

_M32 = 0xFFFFFFFF
# numpy.random.SeedSequence's constants (bit_generator.pyx)
_INIT_A, _MULT_A = 0x43B0D7E5, 0x931E8875
_INIT_B, _MULT_B = 0x8B51F9DD, 0x58F38DED
_MIX_L, _MIX_R = 0xCA01F9DD, 0x4973F715
_POOL = 4
# PCG64's 128-bit LCG multiplier (pcg64.h: PCG_DEFAULT_MULTIPLIER_HIGH, _LOW)
_PCG_MULT = (2549297995355413924 << 64) | 4865540595714422341
_MULT_LIMBS = tuple((_PCG_MULT >> (32 * k)) & _M32 for k in range(4))
#: The largest index computed as arrays (one 32-bit entropy word); larger ones go one by one.
MAX_VECTOR_INDEX = _M32


def _words(n: int) -> list[int]:
    """A non-negative int as SeedSequence's little-endian 32-bit words (0 is one word)."""
    words = [n & _M32]
    n >>= 32
    while n:
        words.append(n & _M32)
        n >>= 32
    return words


def _hasher(init: int, mult: int):
    """SeedSequence's hash step with its running constant (``hashmix`` while mixing the pool,
    the same step with other constants in ``generate_state``): a function of 32-bit values."""
    h = init

    def step(value: np.ndarray) -> np.ndarray:
        nonlocal h
        value = value ^ np.uint64(h)
        h = (h * mult) & _M32
        value = (value * np.uint64(h)) & np.uint64(_M32)
        return value ^ (value >> np.uint64(16))

    return step


def _pool_words(seed: int, indices: np.ndarray) -> list[np.ndarray]:
    """The 4 pool words of ``SeedSequence([seed, i])`` for every ``i`` (< 2**32), as uint64
    arrays holding 32-bit values."""
    n = len(indices)
    entropy = [np.full(n, w, dtype=np.uint64) for w in _words(seed)] + [indices.astype(np.uint64)]
    hashmix = _hasher(_INIT_A, _MULT_A)

    def mix(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        result: np.ndarray = np.bitwise_and(x * np.uint64(_MIX_L) - y * np.uint64(_MIX_R), np.uint64(_M32))
        return result ^ (result >> np.uint64(16))

    zero = np.zeros(n, dtype=np.uint64)
    pool = [hashmix(entropy[i] if i < len(entropy) else zero) for i in range(_POOL)]
    for src in range(_POOL):
        for dst in range(_POOL):
            if src != dst:
                pool[dst] = mix(pool[dst], hashmix(pool[src]))
    for src in range(_POOL, len(entropy)):
        for dst in range(_POOL):
            pool[dst] = mix(pool[dst], hashmix(entropy[src]))
    return pool


def _state_words(pool: list[np.ndarray]) -> list[np.ndarray]:
    """``generate_state(4, uint64)`` of the pool, as 8 little-endian 32-bit words."""
    step = _hasher(_INIT_B, _MULT_B)
    return [step(pool[k % _POOL]) for k in range(8)]


def _limbs(hi: tuple[np.ndarray, np.ndarray], lo: tuple[np.ndarray, np.ndarray]) -> list[np.ndarray]:
    """A 128-bit number from its two 64-bit words, each given as (low, high) 32-bit halves:
    4 limbs, least significant first."""
    return [lo[0], lo[1], hi[0], hi[1]]


def _carry(sums: list[np.ndarray]) -> list[np.ndarray]:
    out: list[np.ndarray] = []
    carry: np.ndarray | np.uint64 = np.uint64(0)
    for s in sums:
        s = s + carry
        carry = s >> np.uint64(32)
        out.append(s & np.uint64(_M32))
    return out


def _add(a: list[np.ndarray], b: list[np.ndarray]) -> list[np.ndarray]:
    return _carry([x + y for x, y in zip(a, b)])


def _times_mult(a: list[np.ndarray]) -> list[np.ndarray]:
    """``a * PCG_MULT mod 2**128``: 32x32-bit products split into halves, summed per limb."""
    sums = [np.zeros_like(a[0]) for _ in range(4)]
    m32 = np.uint64(_M32)
    for i in range(4):
        for j in range(4 - i):
            product = a[i] * np.uint64(_MULT_LIMBS[j])
            sums[i + j] += product & m32
            if i + j + 1 < 4:
                sums[i + j + 1] += product >> np.uint64(32)
    return _carry(sums)


def _pcg64_doubles(words: list[np.ndarray], first: int, count: int) -> np.ndarray:
    """Doubles ``first`` to ``first + count - 1`` of PCG64 seeded with ``words`` (seed then
    increment, as ``pcg64_set_seed``), as ``Generator.random`` makes them."""
    initstate = _limbs((words[0], words[1]), (words[2], words[3]))
    initseq = _limbs((words[4], words[5]), (words[6], words[7]))
    # inc = initseq << 1 | 1
    inc = [(initseq[k] << np.uint64(1)) & np.uint64(_M32) for k in range(4)]
    for k in range(1, 4):
        inc[k] |= initseq[k - 1] >> np.uint64(31)
    inc[0] |= np.uint64(1)
    state = _add(_times_mult(_add(inc, initstate)), inc)  # (0 * M + inc + initstate) * M + inc
    for _ in range(first):
        state = _add(_times_mult(state), inc)
    out = np.empty((len(words[0]), count))
    for c in range(count):
        state = _add(_times_mult(state), inc)
        hi = (state[3] << np.uint64(32)) | state[2]
        lo = (state[1] << np.uint64(32)) | state[0]
        x = hi ^ lo
        rot = state[3] >> np.uint64(26)
        x = (x >> rot) | (x << ((np.uint64(64) - rot) & np.uint64(63)))
        out[:, c] = (x >> np.uint64(11)).astype(np.float64) * (1.0 / 9007199254740992.0)
    return out


def stream_doubles(seed: int, indices: np.ndarray, first: int, count: int) -> np.ndarray:
    """``(len(indices), count)``: doubles ``first`` .. ``first + count - 1`` of
    ``Generator(PCG64(SeedSequence([seed, i]))).random()`` for each episode ``i``."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SpecError(f"seed must be a non-negative integer, got {shorten(repr(seed))}")
    if isinstance(first, bool) or not isinstance(first, int) or first < 0:
        raise SpecError(f"first must be a non-negative integer, got {shorten(repr(first))}")
    if isinstance(count, bool) or not isinstance(count, int) or count < 0:
        raise SpecError(f"count must be a non-negative integer, got {shorten(repr(count))}")
    indices = np.asarray(indices)
    if indices.ndim != 1 or (indices.size and (indices.dtype.kind not in "iu" or indices.min() < 0)):
        raise SpecError(f"indices must be a 1-D array of non-negative integers, got {indices!r:.80}")
    out = np.empty((len(indices), count))
    small = indices <= MAX_VECTOR_INDEX
    if small.any():
        pool = _pool_words(int(seed), indices[small])
        out[small] = _pcg64_doubles(_state_words(pool), first, count)
    for row in np.flatnonzero(~small):
        bits = np.random.PCG64(np.random.SeedSequence([int(seed), int(indices[row])]))
        bits.advance(first)
        out[row] = np.random.Generator(bits).random(count)
    return out
