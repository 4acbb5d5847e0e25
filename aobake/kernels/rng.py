"""Counter-based randomness: every random number is a pure function of its counters.

Results therefore do not depend on thread count, chunking or scheduling (numba keeps
per-thread ``np.random`` state, which would). Arithmetic stays in ``np.uint64`` with
explicit masks: in numba, mixing uint64 and int64 promotes to float64.
"""

from __future__ import annotations

import numpy as np
from numba import njit

_M32 = np.uint64(0xFFFFFFFF)
_INV32 = 1.0 / 4294967296.0


@njit(cache=True, inline="always")
def mix64(x):
    """SplitMix64 finaliser: a bijective avalanche on 64-bit words."""
    x = np.uint64(x)
    x ^= x >> np.uint64(30)
    x *= np.uint64(0xBF58476D1CE4E5B9)
    x ^= x >> np.uint64(27)
    x *= np.uint64(0x94D049BB133111EB)
    x ^= x >> np.uint64(31)
    return x


@njit(cache=True, inline="always")
def hash2(a, b):
    """Hash of two 64-bit counters (order matters)."""
    return mix64(np.uint64(a) ^ mix64(np.uint64(b) + np.uint64(0x9E3779B97F4A7C15)))


@njit(cache=True, inline="always")
def reverse_bits32(x):
    """Reverse the low 32 bits of ``x`` (a uint64 holding a 32-bit word)."""
    x = np.uint64(x) & _M32
    x = ((x >> np.uint64(1)) & np.uint64(0x55555555)) | (
        (x & np.uint64(0x55555555)) << np.uint64(1)
    )
    x = ((x >> np.uint64(2)) & np.uint64(0x33333333)) | (
        (x & np.uint64(0x33333333)) << np.uint64(2)
    )
    x = ((x >> np.uint64(4)) & np.uint64(0x0F0F0F0F)) | (
        (x & np.uint64(0x0F0F0F0F)) << np.uint64(4)
    )
    x = ((x >> np.uint64(8)) & np.uint64(0x00FF00FF)) | (
        (x & np.uint64(0x00FF00FF)) << np.uint64(8)
    )
    x = ((x >> np.uint64(16)) & np.uint64(0x0000FFFF)) | (
        (x & np.uint64(0x0000FFFF)) << np.uint64(16)
    )
    return x & _M32


@njit(cache=True, inline="always")
def owen_permute_reversed(x, seed):
    """Hash-based nested uniform permutation of a bit-reversed 32-bit word.

    Each output bit depends only on the input bits below it, which on the reversed
    word means each digit of the fraction depends only on the digits above it: the
    defining property of an Owen scramble (Laine & Karras 2011; constants from
    Vegdahl's improved variant).
    """
    x = np.uint64(x) & _M32
    s = np.uint64(seed) & _M32
    x ^= (x * np.uint64(0x3D20ADEA)) & _M32
    x = (x + s) & _M32
    x = (x * ((s >> np.uint64(16)) | np.uint64(1))) & _M32
    x ^= (x * np.uint64(0x05526C56)) & _M32
    x ^= (x * np.uint64(0x53A22864)) & _M32
    return x


@njit(cache=True, inline="always")
def owen_scramble32(x, seed):
    """Owen-scramble a 32-bit fixed-point fraction ``x`` with ``seed``."""
    return reverse_bits32(owen_permute_reversed(reverse_bits32(x), seed))


@njit(cache=True, inline="always")
def sobol2_32(index):
    """First two dimensions of the Sobol sequence as 32-bit fractions.

    Dimension 0 is van der Corput (bit reversal); dimension 1 uses the direction numbers
    v_0 = 2^31, v_{k+1} = v_k ^ (v_k >> 1). Every aligned block of 2^k points is a
    (0, k, 2)-net: stratified in every elementary interval of area 2^-k.
    """
    i = np.uint64(index) & _M32
    x0 = reverse_bits32(i)
    x1 = np.uint64(0)
    v = np.uint64(0x80000000)
    while i != np.uint64(0):
        if i & np.uint64(1):
            x1 ^= v
        i >>= np.uint64(1)
        v ^= v >> np.uint64(1)
    return x0, x1


@njit(cache=True, inline="always")
def scramble_seeds(key):
    """The two per-dimension Owen seeds of a sequence keyed by ``key``."""
    return hash2(key, 0) & _M32, hash2(key, 1) & _M32


@njit(cache=True, inline="always")
def scrambled_sobol2_seeded(index, s0, s1):
    """Point ``index`` of the 2-D Sobol sequence Owen-scrambled with seeds (s0, s1)."""
    x0, x1 = sobol2_32(index)
    u0 = float(owen_scramble32(x0, s0)) * _INV32
    u1 = float(owen_scramble32(x1, s1)) * _INV32
    return u0, u1


@njit(cache=True, inline="always")
def sobol1_reversed(index):
    """Dimension 1 of :func:`sobol2_32` bit-reversed, in five masked shifts (no loop
    over the index's bits): reversed, its direction numbers are the rows of Pascal's
    triangle mod 2, so bit j is the parity of the index's set bits k with j a bitwise
    subset of k (Lucas), a transform over subsets made one bit position at a time."""
    y = np.uint64(index) & _M32
    y ^= (y >> np.uint64(1)) & np.uint64(0x55555555)
    y ^= (y >> np.uint64(2)) & np.uint64(0x33333333)
    y ^= (y >> np.uint64(4)) & np.uint64(0x0F0F0F0F)
    y ^= (y >> np.uint64(8)) & np.uint64(0x00FF00FF)
    y ^= (y >> np.uint64(16)) & np.uint64(0x0000FFFF)
    return y


@njit(cache=True, inline="always")
def scrambled_sobol2_fast(index, s0, s1):
    """:func:`scrambled_sobol2_seeded` bit for bit in fewer operations (~6 ns a point
    less): the scramble works on bit-reversed words, so dimension 0 (the reversed
    index) is never reversed twice and dimension 1 is made reversed
    (:func:`sobol1_reversed`)."""
    i = np.uint64(index) & _M32
    u0 = float(reverse_bits32(owen_permute_reversed(i, s0))) * _INV32
    u1 = float(reverse_bits32(owen_permute_reversed(sobol1_reversed(i), s1))) * _INV32
    return u0, u1


@njit(cache=True, inline="always")
def scrambled_sobol2(index, key):
    """Point ``index`` of a 2-D Owen-scrambled Sobol sequence keyed by ``key``, in [0, 1)^2."""
    s0, s1 = scramble_seeds(key)
    return scrambled_sobol2_seeded(index, s0, s1)


@njit(cache=True, inline="always")
def random2(index, key):
    """Two independent uniform numbers in [0, 1) from (key, index): plain random, no strata."""
    return random2_hashed(index_hash(index), key)


@njit(cache=True, inline="always")
def index_hash(index):
    """The part of :func:`random2`'s hash that depends on ``index`` alone (the inner
    hash of :func:`hash2`), made once where many keys share an index."""
    return mix64(np.uint64(index) + np.uint64(0x632BE59BD9B4E019) + np.uint64(0x9E3779B97F4A7C15))


@njit(cache=True, inline="always")
def random2_hashed(hashed, key):
    """:func:`random2` (index, key) from ``hashed = index_hash(index)``: the same numbers."""
    h = mix64(np.uint64(key) ^ hashed)
    u0 = float(h >> np.uint64(32)) * _INV32
    u1 = float(mix64(h) >> np.uint64(32)) * _INV32
    return u0, u1


@njit(cache=True)
def _element_key(seed, element):
    return hash2(seed, element)


@njit(cache=True)
def sample_points(seed, element, n, stratified):
    """(n, 2) samples of ``element`` under ``seed``: scrambled Sobol or plain random.

    Test and inspection helper; the ray kernels call the scalar functions directly.
    """
    key = hash2(np.uint64(seed), np.uint64(element))
    out = np.zeros((n, 2))
    for j in range(n):
        if stratified:
            u0, u1 = scrambled_sobol2(j, key)
        else:
            u0, u1 = random2(j, key)
        out[j, 0] = u0
        out[j, 1] = u1
    return out
