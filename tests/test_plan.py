"""aobake.plan: which effects a scene calls for, and which receivers each light reaches."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aobake.mesh import surface_from_arrays
from aobake.plan import make_plan, reach
from aobake.shading import Light, Shading, default_shading


def _floor(n: int = 5):
    """An n x n grid of points on z = 0 facing +z, spanning [-1, 1]^2."""
    t = np.linspace(-1.0, 1.0, n)
    x, y = np.meshgrid(t, t, indexing="ij")
    positions = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], axis=1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return surface_from_arrays(positions, faces)


def _brute_reach(light: Light, x: np.ndarray, n: np.ndarray, samples: np.ndarray) -> bool:
    """Reach by sampling the light's surface densely: some sample in front of the tangent
    plane (and the receiver on the emitting side)."""
    d = samples - x
    front = d @ n > 1e-12
    if light.kind in ("rect", "disk"):
        front &= (x - light.position) @ light.normal > 0
    return bool(front.any())


@pytest.mark.parametrize("kind", ["rect", "disk", "sphere"])
def test_area_reach_matches_dense_sampling(kind):
    rng = np.random.default_rng(3)
    light = {
        "rect": Light.make("rect", "r", (1, 1, 1), position=(0.2, 0.1, 0.5), u=(0.4, 0.1, 0.0), v=(0.0, 0.3, -0.2)),
        "disk": Light.make("disk", "d", (1, 1, 1), position=(0.2, 0.1, 0.5), radius=0.4, normal=(0.3, 0.2, -1.0)),
        "sphere": Light.make("sphere", "s", (1, 1, 1), position=(0.2, 0.1, 0.5), radius=0.3),
    }[kind]
    # dense samples of the light's surface
    s = rng.uniform(-1, 1, (20000, 2))
    if kind == "rect":
        samples = light.position + s[:, :1] * light.u + s[:, 1:] * light.v
    elif kind == "disk":
        m = light.normal
        e1 = np.cross(m, [1.0, 0, 0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(m, e1)
        s = s[np.einsum("ij,ij->i", s, s) <= 1]
        samples = light.position + light.radius * (s[:, :1] * e1 + s[:, 1:] * e2)
    else:
        d = rng.normal(size=(20000, 3))
        samples = light.position + light.radius * d / np.linalg.norm(d, axis=1)[:, None]
    x = rng.uniform(-1.5, 1.5, (300, 3))
    n = rng.normal(size=(300, 3))
    n /= np.linalg.norm(n, axis=1)[:, None]
    if kind == "sphere":
        keep = np.linalg.norm(x - light.position, axis=1) > light.radius
        x, n = x[keep], n[keep]
    got = reach(light, x, n)
    want = np.array([_brute_reach(light, xi, ni, samples) for xi, ni in zip(x, n, strict=True)])
    # sampling can miss a sliver of the light seen at grazing angles: allow 1% there only
    assert np.count_nonzero(got != want) <= 0.01 * len(x)
    assert np.all(got | ~want)  # never out of reach where a sample is in front


def test_point_spot_distant_reach():
    x = np.array([[0.0, 0, 0], [0, 0, 0], [5, 0, 0], [0, 0, 0]])
    n = np.array([[0.0, 0, 1], [0, 0, -1], [0, 0, 1], [0, 0, 0]])
    point = Light.make("point", "p", (1, 1, 1), position=(0, 0, 1), range=3.0)
    assert reach(point, x, n).tolist() == [True, False, False, False]  # behind, beyond range, no normal
    spot = Light.make("spot", "s", (1, 1, 1), position=(0, 0, 1), direction=(0, 0, -1), cone_outer=math.radians(30))
    far = np.array([[0.0, 0, 0], [0.5, 0, 0], [0.6, 0, 0]])  # tan(30 deg) = 0.577
    assert reach(spot, far, np.tile([0.0, 0, 1], (3, 1))).tolist() == [True, True, False]
    sun = Light.make("distant", "d", (1, 1, 1), direction=(1, 0, 0.01))
    assert reach(sun, x[:2], n[:2]).tolist() == [True, False]
    grazing = Light.make("distant", "d", (1, 1, 1), direction=(1, 0, -0.05), angle=0.2)  # below, half-angle 0.1
    assert reach(grazing, x[:1], n[:1]).tolist() == [True]


def test_auto_effects():
    s = _floor()
    assert make_plan(s, None).effects == ("ao",)
    assert make_plan(s, default_shading(s.n_vertices, s.n_faces)).effects == ("ao",)
    light = Light.make("point", "p", (2, 2, 2), position=(0, 0, 1))
    sh = default_shading(s.n_vertices, s.n_faces, [light])
    assert make_plan(s, sh).effects == ("ao", "direct", "indirect")
    assert make_plan(s, sh, bounces=0).effects == ("ao", "direct")
    black = Shading(sh.lights, 0 * sh.face_albedo, sh.face_emission, 0 * sh.vertex_albedo, sh.vertex_emission)
    plan = make_plan(s, black)
    assert plan.effects == ("ao", "direct") and "albedo" in plan.reasons["indirect"]
    assert make_plan(s, sh, effects=("ao",)).effects == ("ao",)
    with pytest.raises(ValueError, match="needs direct"):
        make_plan(s, sh, effects=("ao", "indirect"))
    with pytest.raises(ValueError, match="does not call for it"):
        make_plan(s, default_shading(s.n_vertices, s.n_faces), effects=("direct",))


def test_skipped_lights_and_counts():
    s = _floor()
    below = Light.make("point", "/World/below", (1, 1, 1), position=(0, 0, -1))
    off = Light.make("point", "/World/off", (0, 0, 0), position=(0, 0, 1))
    unshadowed = Light.make("point", "/World/noshadow", (1, 1, 1), position=(0, 0, 1), shadow=False)
    area = Light.make("rect", "/World/rect", (1, 1, 1), position=(0, 0, 1), u=(0.1, 0, 0), v=(0, -0.1, 0))
    sh = default_shading(s.n_vertices, s.n_faces, [below, off, unshadowed, area])
    plan = make_plan(s, sh, ao_rays=4, area_samples=8, indirect_rays=2)
    by_name = {p.light.name: p for p in plan.lights}
    assert by_name["/World/below"].reach == 0 and by_name["/World/below"].why_skipped
    assert by_name["/World/off"].why_skipped.startswith("black")
    assert by_name["/World/noshadow"].reach == s.n_vertices and by_name["/World/noshadow"].shadow_rays == 0
    assert by_name["/World/rect"].shadow_rays == 8 * s.n_vertices
    assert plan.rays["ao"] == 4 * s.n_vertices and plan.rays["shadow"] == 8 * s.n_vertices
    assert "/World/below" in plan.summary() and "/World/off" in plan.summary()
    assert "expected rays" in plan.report()
