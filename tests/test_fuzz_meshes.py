"""Hypothesis mesh fuzzing (issue 19): random vertices, faces, degenerate and repeated
corners, extreme scales and offsets. Every mesh either is refused with a one-line
InputError naming it, or bakes to finite ao in [0, 1] with its vertex count, with both
the ray and the disk method. Small meshes and few rays: cheap enough for CI."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import aobake
from aobake.errors import InputError
from aobake.mesh import surface_from_arrays


@st.composite
def meshes(draw):
    n = draw(st.integers(1, 9))
    coords = draw(
        st.lists(
            st.one_of(st.integers(-8, 8).map(float), st.floats(-1, 1, allow_nan=False)),
            min_size=3 * n,
            max_size=3 * n,
        )
    )
    positions = np.array(coords).reshape(n, 3)
    # faces may repeat corners (zero area) and index beyond n (refused)
    m = draw(st.integers(0, 8))
    faces = np.array(
        draw(st.lists(st.integers(0, n), min_size=3 * m, max_size=3 * m)), dtype=np.int64
    ).reshape(m, 3)
    scale = 10.0 ** draw(st.sampled_from([-40, -30, -15, -3, 0, 5, 15, 20, 30, 38]))
    offset = draw(st.sampled_from([0.0, 1.0, 1e6]))
    return positions * scale + offset * scale, faces


def _check(positions, faces, method, **options):
    try:
        surface = surface_from_arrays(positions, faces, source="fuzz.ply")
        ao = np.asarray(aobake.bake(surface, method, **options))
    except InputError as exc:
        text = str(exc)
        assert text.startswith("fuzz.ply: ") and "\n" not in text
        return
    assert ao.shape == (positions.shape[0],)
    assert np.isfinite(ao).all() and ao.min() >= 0.0 and ao.max() <= 1.0


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mesh=meshes())
def test_fuzz_embree(mesh):
    _check(*mesh, "embree", n_rays=8)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mesh=meshes())
def test_fuzz_bunnell(mesh):
    _check(*mesh, "bunnell")


@settings(max_examples=20, deadline=None)
@given(
    scale=st.sampled_from([1e-40, 1e-30, 1e-15, 1e15, 1e20, 1e30, 2e38]),
    seed=st.integers(0, 1000),
)
def test_fuzz_closed_box_reads_closed_at_any_scale(scale, seed):
    # A vertex inside a closed box (an inward-facing cube around a tiny triangle) is
    # fully occluded whatever the scale: main read these open above ~1e13.
    import trimesh

    box = trimesh.creation.box(extents=(2, 2, 2))
    rng = np.random.default_rng(seed)
    centre = rng.uniform(-0.5, 0.5, 3)
    tri = centre + 1e-3 * rng.normal(size=(3, 3))
    positions = np.vstack([box.vertices, tri]) * scale
    faces = np.vstack([box.faces[:, ::-1], [[8, 9, 10]]])
    ao = aobake.bake(surface_from_arrays(positions, faces), "embree", n_rays=8, seed=seed)
    np.testing.assert_array_equal(np.asarray(ao), 0.0)


@st.composite
def needles(draw):
    """1-3 needle or almost collinear triangles (widths 1e-16..1e-3 of their length),
    sometimes over a floor, at a scale from 1e-30 to 2e38."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    points, faces = [], []
    for _ in range(draw(st.integers(1, 3))):
        a = rng.normal(size=3)
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        perp = np.cross(d, rng.normal(size=3))
        perp /= np.linalg.norm(perp)
        length, width = 10 ** rng.uniform(-1, 1), 10 ** rng.uniform(-16, -3)
        if draw(st.booleans()):
            tri = [a, a + length * d, a + rng.uniform(0, 1) * length * d + width * perp]
        else:
            tri = [a, a + length * d, a + 2 * length * d * (1 + width)]
        faces.append([len(points), len(points) + 1, len(points) + 2])
        points += tri
    if draw(st.booleans()):
        k = len(points)
        points += [[-5, -5, -3], [5, -5, -3], [5, 5, -3], [-5, 5, -3]]
        faces += [[k, k + 1, k + 2], [k, k + 2, k + 3]]
    scale = draw(st.sampled_from([1e-30, 1.0, 1e20, 1e30, 2e38]))
    return np.array(points, dtype=np.float64) * scale, np.array(faces)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mesh=needles(), passes=st.sampled_from([1, 2]))
def test_fuzz_needles_bunnell(mesh, passes):
    _check(*mesh, "bunnell", passes=passes)
