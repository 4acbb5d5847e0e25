"""Warps, frames and sample sets: spot values, distributions, stratification."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from aobake.kernels import rng, warps
from aobake.sampling import sample_directions, unit_square_samples


def test_concentric_map_spot_values():
    assert warps.square_to_uniform_disk_concentric(0.5, 0.5) == (0.0, 0.0)
    x, y = warps.square_to_uniform_disk_concentric(1.0, 0.5)
    np.testing.assert_allclose((x, y), (1.0, 0.0), atol=1e-15)
    x, y = warps.square_to_uniform_disk_concentric(0.5, 1.0)
    np.testing.assert_allclose((x, y), (0.0, 1.0), atol=1e-15)


@pytest.mark.parametrize(
    "warp", [warps.square_to_cosine_hemisphere, warps.square_to_uniform_hemisphere]
)
def test_hemisphere_warps_unit_and_upper(warp):
    u = unit_square_samples(3, 7, 1024)
    d = np.array([warp(a, b) for a, b in u])
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    assert (d[:, 2] >= 0.0).all()


def _binned_uniformity(values: np.ndarray, bins: int) -> None:
    """Counts of uniform values in equal bins sit within 5 binomial sigmas."""
    counts = np.histogram2d(values[:, 0], values[:, 1], bins=bins, range=[[0, 1], [0, 1]])[
        0
    ].ravel()
    n = values.shape[0]
    p = 1.0 / bins**2
    sigma = math.sqrt(n * p * (1 - p))
    assert np.abs(counts - n * p).max() < 5 * sigma


def test_cosine_hemisphere_distribution():
    # For cosine-weighted directions (cos^2 theta, phi / 2pi) is uniform on the unit square.
    rs = np.random.default_rng(0).random((20000, 2))
    d = np.array([warps.square_to_cosine_hemisphere(a, b) for a, b in rs])
    phi = (np.arctan2(d[:, 1], d[:, 0]) / (2 * np.pi)) % 1.0
    _binned_uniformity(np.c_[d[:, 2] ** 2, phi], 8)


def test_uniform_hemisphere_distribution():
    # For uniform directions (cos theta, phi / 2pi) is uniform on the unit square.
    rs = np.random.default_rng(1).random((20000, 2))
    d = np.array([warps.square_to_uniform_hemisphere(a, b) for a, b in rs])
    phi = (np.arctan2(d[:, 1], d[:, 0]) / (2 * np.pi)) % 1.0
    _binned_uniformity(np.c_[d[:, 2], phi], 8)


def test_pdfs_integrate_to_one():
    # Riemann sum over the hemisphere in (cos theta, phi): d omega = d(cos) d(phi).
    z = (np.arange(2000) + 0.5) / 2000
    np.testing.assert_allclose(
        sum(warps.cosine_hemisphere_pdf(c) for c in z) / 2000 * 2 * np.pi, 1.0, rtol=1e-6
    )
    assert warps.uniform_hemisphere_pdf(0.3) * 2 * np.pi == pytest.approx(1.0)
    assert warps.uniform_sphere_pdf() * 4 * np.pi == pytest.approx(1.0)


unit_vectors = st.tuples(
    st.floats(-1, 1, allow_nan=False),
    st.floats(-1, 1, allow_nan=False),
    st.floats(-1, 1, allow_nan=False),
).filter(lambda v: 1e-3 < math.sqrt(sum(c * c for c in v)))


@given(unit_vectors)
def test_frame_is_orthonormal(v):
    n = np.array(v) / np.linalg.norm(v)
    tx, ty, tz, bx, by, bz = warps.frame(*n)
    m = np.array([[tx, ty, tz], [bx, by, bz], n])
    np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(m) == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("n", [(0, 0, 1), (0, 0, -1), (1e-9, 0, -1), (0, 1e-12, 1), (1, 0, 0)])
def test_frame_axis_cases(n):
    n = np.array(n, dtype=float) / np.linalg.norm(n)
    tx, ty, tz, bx, by, bz = warps.frame(*n)
    m = np.array([[tx, ty, tz], [bx, by, bz], n])
    np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-12)


def test_sobol_prefixes_are_stratified():
    # Every power-of-two prefix of the scrambled (0,2)-sequence puts exactly one point
    # in each cell of every elementary 2^a x 2^b grid with a + b = m.
    u = unit_square_samples(11, 5, 256)
    for m in (2, 4, 6, 8):
        pts = u[: 2**m]
        for a in range(m + 1):
            b = m - a
            cells = np.floor(pts[:, 0] * 2**a).astype(int) * 2**b + np.floor(
                pts[:, 1] * 2**b
            ).astype(int)
            assert np.bincount(cells, minlength=2**m).max() == 1


def test_scrambles_differ_between_vertices_and_seeds():
    a = unit_square_samples(0, 0, 16)
    assert not np.array_equal(a, unit_square_samples(0, 1, 16))
    assert not np.array_equal(a, unit_square_samples(1, 0, 16))
    np.testing.assert_array_equal(a, unit_square_samples(0, 0, 16))


def test_scrambled_points_are_uniform_across_vertices():
    # Owen scrambling randomises each point uniformly: point 0 over many keys.
    pts = np.array([unit_square_samples(0, v, 1)[0] for v in range(4000)])
    _binned_uniformity(pts, 4)


def _random2_reference(index, key):
    """random2 in Python integers: SplitMix64's finaliser, hash2(key, index + c)."""
    m = (1 << 64) - 1

    def mix(x):
        x ^= x >> 30
        x = (x * 0xBF58476D1CE4E5B9) & m
        x ^= x >> 27
        x = (x * 0x94D049BB133111EB) & m
        return x ^ (x >> 31)

    h = mix(key ^ mix((index + 0x632BE59BD9B4E019 + 0x9E3779B97F4A7C15) & m))
    return (h >> 32) / 2**32, (mix(h) >> 32) / 2**32


def test_random2_and_its_split_hash_match_the_formula():
    # The paths hash a sample's index once for all keys (index_hash, random2_hashed):
    # the same numbers as random2, which are the formula's.
    from aobake.kernels.lights import path_hashes

    keys = [0, 1, 0x9E3779B97F4A7C15, (1 << 64) - 1]
    hashes = path_hashes(5, 300)
    for key in keys:
        for index in (5, 6, 77, 299):
            want = _random2_reference(index, key)
            assert rng.random2(index, np.uint64(key)) == want
            assert rng.random2_hashed(hashes[index - 5], np.uint64(key)) == want


def _sobol1_reference(index):
    """Dimension 1 of the Sobol sequence in Python integers: the XOR of the direction
    numbers v_0 = 2^31, v_(k+1) = v_k ^ (v_k >> 1) of the index's set bits."""
    x, v = 0, 1 << 31
    while index:
        if index & 1:
            x ^= v
        index >>= 1
        v ^= v >> 1
    return x


def test_fast_sobol_point_is_the_looped_one():
    # The light kernels' point (five masked shifts, no double reversal) must be the
    # AO's bit for bit: same seeds, any 32-bit index.
    indices = [0, 1, 2, 3, 255, 256, 1023, 1024, 12345, (1 << 31) - 1, 1 << 31, (1 << 32) - 1]
    indices += [int(i) for i in np.random.default_rng(4).integers(0, 1 << 32, 200)]
    for i in indices:
        want = int(f"{_sobol1_reference(i):032b}"[::-1], 2)
        assert rng.sobol1_reversed(np.uint64(i)) == want
    for s0, s1 in ((0, 0), (0x12345678, 0x9ABCDEF0), (0xFFFFFFFF, 1)):
        for i in indices:
            got = rng.scrambled_sobol2_fast(np.uint64(i), np.uint64(s0), np.uint64(s1))
            assert got == rng.scrambled_sobol2_seeded(np.uint64(i), np.uint64(s0), np.uint64(s1))


def test_branch_free_first_directions_are_the_warps():
    # The AO's and the paths' first directions are made by selects, not branches (so the loop
    # vectorises): the concentric map and the cosine warp of the Sobol point, bit for bit.
    from aobake.kernels.rays import sobol_cosine_direction
    from aobake.kernels.warps import concentric_selects

    u = np.random.default_rng(5).integers(0, 1 << 32, (400, 2)) / 2**32
    special = [0.0, 0.25, 0.5, 0.75, 1 - 2**-32, 0.5 + 2**-32, 0.5 - 2**-32]
    pairs = [tuple(x) for x in u] + [(a, b) for a in special for b in special]
    pairs += [(x, x) for x in u[:50, 0]] + [(x, 1.0 - x) for x in u[:50, 0]]  # the wedges' diagonals
    for u0, u1 in pairs:
        assert concentric_selects(u0, u1) == warps.square_to_uniform_disk_concentric(u0, u1)
    assert concentric_selects(0.5, 0.5) == (0.0, 0.0)
    for s0, s1 in ((0, 0), (0x2545F491, 0x4F6CDD1D)):
        for i in [0, 1, 2, 3, 1023, 1 << 20, (1 << 32) - 1]:
            uv = rng.scrambled_sobol2_seeded(np.uint64(i), np.uint64(s0), np.uint64(s1))
            assert sobol_cosine_direction(i, np.uint64(s0), np.uint64(s1)) == warps.square_to_cosine_hemisphere(*uv)


def test_reverse_bits():
    assert rng.reverse_bits32(np.uint64(1)) == np.uint64(0x80000000)
    assert rng.reverse_bits32(np.uint64(0x80000000)) == np.uint64(1)
    assert rng.reverse_bits32(np.uint64(0xF0)) == np.uint64(0x0F000000)


def test_sample_directions_follow_normals():
    normals = np.array([[0, 0, 1.0], [1.0, 0, 0], [0, -0.6, 0.8], [0, 0, 0]])
    d = sample_directions(normals, 64, seed=2)
    assert d.shape == (4, 64, 3)
    cos = np.einsum("vkj,vj->vk", d.astype(np.float64), normals)
    assert (cos[:3] >= -1e-6).all()
    # zero normal: whole sphere, both hemispheres used
    assert (d[3, :, 2] > 0).any() and (d[3, :, 2] < 0).any()
    # chunking of sample indices does not change directions
    np.testing.assert_array_equal(d[:, 16:32], sample_directions(normals, 16, seed=2, start=16))


@pytest.mark.parametrize("measure", ["cosine", "uniform"])
@pytest.mark.parametrize("stratified", [True, False])
def test_sample_directions_are_the_scalar_warps(measure, stratified):
    # generate_rays makes a vertex's directions in a loop (vectorised for the default):
    # each must be the scalar warp of its own point, turned into the normal's frame.
    from aobake.kernels import rays as _k

    normals = np.array([[0, 0, 1.0], [0, 0, -1.0], [1.0, 0, 0], [0, -0.6, 0.8], [0, 0, 0], [0.48, 0.6, -0.64]])
    keys = _k.vertex_keys(np.uint64(9), normals.shape[0])
    d = sample_directions(normals, 12, seed=9, measure=measure, stratified=stratified, start=5)
    warp = warps.square_to_cosine_hemisphere if measure == "cosine" else warps.square_to_uniform_hemisphere
    for v, (nx, ny, nz) in enumerate(normals):
        s0, s1 = rng.scramble_seeds(keys[v])
        for s in range(12):
            j = np.uint64(5 + s)
            uv = rng.scrambled_sobol2_seeded(j, s0, s1) if stratified else rng.random2(j, keys[v])
            if nx == ny == nz == 0.0:
                want = warps.square_to_uniform_sphere(*uv)
            else:
                x, y, z = warp(*uv)
                tx, ty, tz, bx, by, bz = warps.frame(nx, ny, nz)
                want = (x * tx + y * bx + z * nx, x * ty + y * by + z * ny, x * tz + y * bz + z * nz)
            assert d[v, s].tolist() == np.array(want, dtype=np.float32).tolist(), (v, s)
