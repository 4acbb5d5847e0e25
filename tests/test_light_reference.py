"""The ray-traced irradiance reference (aobake.methods.embree.light) against closed forms:
disk, sphere, rectangle, point, spot and distant lights, shadows, reach, the furnace."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aobake.mesh import surface_from_arrays
from aobake.methods.embree.light import irradiance
from aobake.plan import reach
from aobake.shading import Light, Shading, default_shading
from aobake.testing.scenes import ground_grid, sphere


def grid(half=1.0, cells=4, z=0.0, normals=None):
    pos, faces = ground_grid(half, cells, z)
    return surface_from_arrays(pos, faces, normals)


def one_point(normal=(0.0, 0.0, 1.0)):
    """A tiny receiver triangle at the origin whose vertex 0 has ``normal``."""
    s = 1e-4
    pos = np.array([[0.0, 0.0, 0.0], [s, 0.0, 0.0], [0.0, s, 0.0]])
    normals = np.tile(np.asarray(normal, dtype=float) / np.linalg.norm(normal), (3, 1))
    return surface_from_arrays(pos, np.array([[0, 1, 2]]), normals)


def lit(surface, lights, **kw):
    return irradiance(surface, default_shading(surface.n_vertices, surface.n_faces, lights), **kw)


def test_coaxial_disk_light():
    R, h, L = 0.7, 1.3, np.array([1.0, 2.0, 0.5])
    light = Light.make("disk", "d", L, position=(0, 0, h), radius=R, normal=(0, 0, -1))
    r = lit(one_point(), [light], n_samples=256, bounces=0)
    want = L * math.pi * R**2 / (R**2 + h**2)
    assert np.allclose(r.direct[0], want, rtol=5e-3)
    assert np.all(np.abs(r.direct[0] - want) <= r.error[0])
    assert r.n_shadow_rays == 3 * 256 and r.n_bounce_rays == 0
    assert np.all(r.indirect == 0)


@pytest.mark.parametrize("tilt", [0.0, 0.6])
def test_sphere_light(tilt):
    """A sphere fully above the horizon: E = L pi (r/d)^2 cos(theta)."""
    r_s, d, L = 0.4, 2.0, 3.0
    normal = (math.sin(tilt), 0.0, math.cos(tilt))
    light = Light.make("sphere", "s", (L, L, L), position=(0, 0, d), radius=r_s)
    res = lit(one_point(normal), [light], n_samples=256, bounces=0)
    want = L * math.pi * (r_s / d) ** 2 * math.cos(tilt)
    assert res.direct[0, 0] == pytest.approx(want, rel=5e-3)


def test_point_light_exact():
    surface = grid()
    p, intensity = np.array([0.3, -0.2, 1.1]), 2.5
    r = lit(surface, [Light.make("point", "p", (intensity,) * 3, position=p)], bounces=0)
    to = p - surface.positions
    dist = np.linalg.norm(to, axis=1)
    want = intensity * to[:, 2] / dist**3
    assert np.allclose(r.direct[:, 1], want, rtol=1e-12)
    assert np.all(r.error == 0)
    assert r.n_shadow_rays == surface.n_vertices


def test_distant_light_exact_and_with_angle():
    normals = np.array([[0.0, 0.0, 1.0], [0.5, 0.0, 0.8], [0.0, -0.6, 0.8]])
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    s = 1e-3
    surface = surface_from_arrays(np.array([[0, 0, 0], [s, 0, 0], [0, s, 0]], float), np.array([[0, 1, 2]]), normals)
    e_perp = np.array([1.5, 1.0, 0.5])
    want = np.outer(normals[:, 2], e_perp)
    r = lit(surface, [Light.make("distant", "sun", e_perp, direction=(0, 0, 1))], bounces=0)
    assert np.allclose(r.direct, want, rtol=1e-12)
    # a cone of apex angle 0.4, fully above every horizon: E = E_perp cos(theta) still
    r = lit(surface, [Light.make("distant", "sun", e_perp, direction=(0, 0, 1), angle=0.4)], bounces=0, n_samples=64)
    assert np.allclose(r.direct, want, rtol=2e-3)
    assert r.n_shadow_rays == 3 * 64


def test_rectangle_corner_formula():
    """A point under the corner of a parallel a x b rectangle at height h (DESIGN.md 5)."""
    a, b, h, L = 1.0, 2.0, 0.8, 1.7
    light = Light.make("rect", "r", (L,) * 3, position=(a / 2, b / 2, h), u=(a / 2, 0, 0), v=(0, -b / 2, 0))
    r = lit(one_point(), [light], n_samples=1024, bounces=0)
    ap, bp = a / h, b / h
    want = L / 2 * (
        ap / math.sqrt(1 + ap**2) * math.atan(bp / math.sqrt(1 + ap**2))
        + bp / math.sqrt(1 + bp**2) * math.atan(ap / math.sqrt(1 + bp**2))
    )
    assert r.direct[0, 0] == pytest.approx(want, rel=5e-3)
    assert abs(r.direct[0, 0] - want) <= r.error[0, 0]


def test_emissive_quad_matches_the_rectangle():
    """Two emitting triangles (a mesh) light a receiver as the same rectangle light does."""
    a, b, h, L = 1.0, 2.0, 0.8, 1.7
    s = 1e-4
    pos = np.array([[0, 0, 0], [s, 0, 0], [0, s, 0], [0, 0, h], [a, 0, h], [a, b, h], [0, b, h]], float)
    faces = np.array([[0, 1, 2], [3, 5, 4], [3, 6, 5]])
    normals = np.array([[0, 0, 1.0]] * 3 + [[0, 0, -1.0]] * 4)
    surface = surface_from_arrays(pos, faces, normals)
    sh = default_shading(surface.n_vertices, surface.n_faces)
    emission = np.zeros((3, 3))
    emission[1:] = L
    sh = Shading((), sh.face_albedo * 0, emission, sh.vertex_albedo, sh.vertex_emission)
    r = irradiance(surface, sh, n_samples=1024, bounces=0)
    ap, bp = a / h, b / h
    want = L / 2 * (
        ap / math.sqrt(1 + ap**2) * math.atan(bp / math.sqrt(1 + ap**2))
        + bp / math.sqrt(1 + bp**2) * math.atan(ap / math.sqrt(1 + bp**2))
    )
    assert r.direct[0, 0] == pytest.approx(want, rel=5e-3)
    assert r.lights[-1].name == "emitters" and r.lights[-1].shadow_rays >= 1024
    # one-sided: the same quad wound the other way emits upwards, away from the receiver
    flipped = surface_from_arrays(pos, np.vstack([faces[:1], faces[1:, ::-1]]), normals)
    r = irradiance(flipped, sh, n_samples=64, bounces=0)
    assert r.direct[0, 0] == 0.0


def test_spot_cone_edge_and_culling():
    surface = grid(half=2.0, cells=8)
    inner, outer, h, intensity = 0.3, 0.5, 1.0, 4.0
    light = Light.make("spot", "s", (intensity,) * 3, position=(0, 0, h), direction=(0, 0, -1), cone_inner=inner, cone_outer=outer)
    r = lit(surface, [light], bounces=0)
    to = light.position - surface.positions
    dist = np.linalg.norm(to, axis=1)
    theta = np.arccos(to[:, 2] / dist)
    ramp = np.clip((np.cos(theta) - math.cos(outer)) / (math.cos(inner) - math.cos(outer)), 0, 1) ** 2
    want = intensity * to[:, 2] / dist**3 * ramp
    assert np.allclose(r.direct[:, 0], want, rtol=1e-12, atol=0)
    outside = theta >= outer
    assert outside.sum() > 0 and ((theta > inner) & ~outside).sum() > 0
    assert r.lights[0].cone == outside.sum()
    assert r.n_shadow_rays == surface.n_vertices - outside.sum()


def test_lights_behind_cost_no_rays():
    surface = grid()
    lights = [
        Light.make("point", "below", (1, 1, 1), position=(0, 0, -1)),
        Light.make("rect", "backwards", (1, 1, 1), position=(0, 0, 1), u=(0.5, 0, 0), v=(0, 0.5, 0)),  # emits up
        Light.make("point", "far", (1, 1, 1), position=(0, 0, 10), range=5.0),
    ]
    r = lit(surface, lights, bounces=0, n_samples=16)
    n = surface.n_vertices
    assert np.all(r.direct == 0) and r.n_shadow_rays == 0
    assert r.lights[0].behind == n and r.lights[1].behind == n and r.lights[2].range == n


def test_shadow_disabled_and_a_shadowing_occluder():
    """A plate between a point light and a floor: its shadow, or none with shadows off."""
    floor_pos, floor_faces = ground_grid(2.0, 8)
    plate_pos, plate_faces = ground_grid(0.5, 1, z=0.5)
    pos = np.vstack([floor_pos, plate_pos])
    faces = np.vstack([floor_faces, plate_faces + len(floor_pos)])
    surface = surface_from_arrays(pos, faces)
    nf = len(floor_pos)
    p = np.array([0.0, 0.0, 1.0])
    to = p - floor_pos
    dist = np.linalg.norm(to, axis=1)
    open_value = 2.0 * to[:, 2] / dist**3
    # the segment to the light crosses z = 0.5 at half way: in the plate when |x|, |y| < 1
    behind_plate = (np.abs(floor_pos[:, 0]) < 1.0 - 1e-9) & (np.abs(floor_pos[:, 1]) < 1.0 - 1e-9)
    edge = np.isclose(np.abs(floor_pos[:, 0]), 1.0) | np.isclose(np.abs(floor_pos[:, 1]), 1.0)
    r = lit(surface, [Light.make("point", "p", (2, 2, 2), position=p)], bounces=0)
    got = r.direct[:nf, 0]
    assert np.all(got[behind_plate] == 0)
    assert np.allclose(got[~behind_plate & ~edge], open_value[~behind_plate & ~edge], rtol=1e-12)
    r = lit(surface, [Light.make("point", "p", (2, 2, 2), position=p, shadow=False)], bounces=0)
    assert np.allclose(r.direct[:nf, 0], open_value, rtol=1e-12)
    assert r.n_shadow_rays == 0 and r.lights[0].shadow_rays == 0
    # --max-distance: a plate farther than that casts no shadow (as for the AO rays)
    r = lit(surface, [Light.make("point", "p", (2, 2, 2), position=p)], bounces=0, max_distance=0.3)
    assert np.allclose(r.direct[:nf, 0], open_value, rtol=1e-12)
    assert r.n_shadow_rays == surface.n_vertices  # every vertex, the plate's too, faces the light


@pytest.mark.parametrize("bounces", [0, 1, 2])
def test_furnace_inside_a_closed_sphere(bounces):
    """Inside a closed sphere emitting L_e with albedo rho: each bounce adds rho^k pi L_e
    (hit points inside faces see the whole sphere), and no energy is gained."""
    rho, le = 0.6, 2.0
    surface = sphere(1.0, 2, inward=True)
    m = surface.n_faces
    sh = default_shading(surface.n_vertices, m)
    sh = Shading((), np.full((m, 3), rho), np.full((m, 3), le), sh.vertex_albedo, sh.vertex_emission)
    r = irradiance(surface, sh, bounces=bounces, n_samples=32, n_indirect=32)
    full = math.pi * le
    # at a vertex the neighbouring faces lean away from the smooth normal's horizon
    assert np.all(r.direct - r.error <= full) and 0.96 * full < r.direct.mean() < full
    want = full * sum(rho**k for k in range(1, bounces + 1))
    assert r.indirect.mean() == pytest.approx(want, rel=0.01, abs=1e-12)
    total = full * sum(rho**k for k in range(bounces + 1))
    assert r.irradiance.mean() <= total * 1.005
    assert np.mean(r.irradiance - r.error <= total) >= 0.99


def test_dome_is_the_ambient_occlusion():
    """A uniform dome: E = pi L (1 - A) with A the AO of the same scene."""
    from aobake.methods.embree import embree_ao
    from aobake.testing.scenes import sphere_on_ground

    surface, _ = sphere_on_ground(subdivisions=1, cells=4)
    r = lit(surface, [Light.make("dome", "sky", (0.5, 0.5, 0.5))], bounces=0, n_indirect=256)
    ao = embree_ao(surface, n_rays=4096, seed=3).ao
    assert np.all(np.abs(r.direct[:, 0] - 0.5 * math.pi * ao) <= r.error[:, 0] + 0.02)
    assert np.abs(r.direct[:, 0] - 0.5 * math.pi * ao).mean() < 0.01


def test_reach_agrees_with_the_plan():
    surface = grid(half=2.0, cells=6)
    lights = [
        Light.make("spot", "s", (1, 1, 1), position=(0.5, 0, 1), direction=(0, 0.3, -1), cone_outer=0.6),
        Light.make("rect", "r", (1, 1, 1), position=(1, 0, 0.2), u=(0, 0.3, 0), v=(0.0, 0, 0.3)),
        Light.make("disk", "d", (1, 1, 1), position=(-1, 0, 0.3), radius=0.5, normal=(1, 0, -0.2)),
        Light.make("point", "p", (1, 1, 1), position=(0, 0, 1), range=1.8),
    ]
    r = lit(surface, lights, bounces=0, n_samples=4)
    for light, stats in zip(lights, r.lights, strict=False):
        k = int(reach(light, surface.positions, surface.normals).sum())
        assert stats.skipped == surface.n_vertices - k, light.name


def box_scene():
    """A floor with a block on it under a rectangle light, a wall beside: shadows and bounces."""
    from aobake.testing.scenes import box

    floor_pos, floor_faces = ground_grid(1.0, 8)
    block = box((0.5, 0.5, 0.5))
    wall_pos, wall_faces = ground_grid(1.0, 4)
    wall_pos = wall_pos[:, [2, 0, 1]] + [-1.0, 0, 1.0]
    parts = [(floor_pos, floor_faces), (block.positions + [0.2, 0.1, 0.25], block.faces), (wall_pos, wall_faces)]
    pos, faces, base = [], [], 0
    for p, f in parts:
        pos.append(p)
        faces.append(f + base)
        base += len(p)
    surface = surface_from_arrays(np.vstack(pos), np.vstack(faces))
    light = Light.make("rect", "key", (5, 4, 3), position=(0, 0, 1.5), u=(0.3, 0, 0), v=(0, -0.3, 0))
    return surface, default_shading(surface.n_vertices, surface.n_faces, [light])


def test_error_estimate_covers_the_true_error():
    surface, sh = box_scene()
    r = irradiance(surface, sh, n_samples=16, n_indirect=16, bounces=1, seed=1)
    ref = irradiance(surface, sh, n_samples=1024, n_indirect=1024, bounces=1, seed=99)
    lit_ = ref.irradiance[:, 0] > 1e-3 * ref.irradiance[:, 0].max()
    covered = np.abs(r.irradiance - ref.irradiance) <= r.error + ref.error
    assert covered[lit_].all(axis=1).mean() >= 0.95
    assert r.indirect.sum() > 0


def test_bit_identical_for_any_thread_count_and_chunking():
    surface, sh = box_scene()
    a = irradiance(surface, sh, n_samples=8, n_indirect=8, bounces=2, threads=1)
    b = irradiance(surface, sh, n_samples=8, n_indirect=8, bounces=2, threads=2, chunk_rays=100)
    for name in ("direct", "indirect", "error"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    c = irradiance(surface, sh, n_samples=8, n_indirect=8, bounces=2, seed=5)
    assert not np.array_equal(a.direct, c.direct)


def test_adaptive_tolerance_stops_easy_vertices():
    surface, sh = box_scene()
    r = irradiance(surface, sh, n_samples=256, n_indirect=64, bounces=0, tolerance=0.05)
    assert r.samples.min() < 256 and r.samples.max() == 256
    full = irradiance(surface, sh, n_samples=256, n_indirect=64, bounces=0)
    good = r.irradiance[:, 0] > 0.05 * r.irradiance[:, 0].max()
    rel = np.abs(r.irradiance - full.irradiance)[good, 0] / full.irradiance[good, 0]
    assert np.mean(rel <= 0.1) >= 0.95


def test_indirect_converges_like_independent_samples():
    """Two seeds' indirect light differ as 1/sqrt(paths): no correlation between a path's
    random numbers biases it (a correlated pair kept the seeds ~20% apart at any count)."""
    surface, sh = box_scene()

    def gap(n):
        a = irradiance(surface, sh, n_samples=4, n_indirect=n, seed=1).indirect
        b = irradiance(surface, sh, n_samples=4, n_indirect=n, seed=2).indirect
        return np.sqrt(((a - b) ** 2).sum() / (b**2).sum())

    assert gap(512) < 0.4 * gap(32)


def test_shading_that_does_not_fit_is_refused():
    surface = grid(cells=1)
    sh = default_shading(surface.n_vertices, surface.n_faces)
    with pytest.raises(ValueError, match="face_albedo has shape"):
        irradiance(surface, Shading((), sh.face_albedo[:1], sh.face_emission, sh.vertex_albedo, sh.vertex_emission))
    with pytest.raises(ValueError, match="above 1"):
        irradiance(surface, Shading((), sh.face_albedo * 10, sh.face_emission, sh.vertex_albedo, sh.vertex_emission))
    with pytest.raises(ValueError, match="non-finite"):
        irradiance(surface, Shading((), sh.face_albedo, sh.face_emission * np.nan, sh.vertex_albedo, sh.vertex_emission))


def test_lazy_exports_and_defaults():
    import aobake.methods.embree as embree

    assert embree.irradiance is irradiance
    opts = embree.LightOptions()
    assert (opts.n_samples, opts.bounces, opts.n_indirect, opts.tolerance) == (64, 1, 256, None)
    with pytest.raises(ValueError, match="bounces"):
        embree.LightOptions(bounces=-1)


def test_last_bounce_ray_only_where_a_dome_can_be_seen():
    """Inside a closed sphere lit by a light without shadows every path hits and its
    next-event sample costs no ray: K bounces cast K rays a path, the K+1-th (it only
    looks for the dome) only when there is a dome, which it then never sees."""
    surface = sphere(1.0, 1, inward=True)
    n, paths = surface.n_vertices, 8
    point = Light.make("point", "p", (1, 1, 1), position=(0.1, 0.0, 0.0), shadow=False)
    dome = Light.make("dome", "sky", (3, 3, 3))
    for bounces in (1, 2):
        plain = lit(surface, [point], bounces=bounces, n_indirect=paths, n_samples=4)
        domed = lit(surface, [point, dome], bounces=bounces, n_indirect=paths, n_samples=4)
        assert plain.n_bounce_rays == n * paths * bounces
        assert domed.n_bounce_rays == n * paths * (bounces + 1)
        for name in ("direct", "indirect", "error"):
            assert np.array_equal(getattr(plain, name), getattr(domed, name)), name
        assert plain.indirect.min() > 0


# -- the ground plane (--ground) ---------------------------------------------------------------


def test_ground_leaves_a_distant_light_and_reflects_it():
    """A tiny receiver 1 above an infinite plane, distant light at 45 degrees: the direct
    term is E_perp cos(theta) bit for bit with or without the plane; a receiver facing
    up sees none of the plane; one facing sideways sees it lit by E_perp (l.up), radiance
    rho E_p / pi over half its hemisphere: E_indirect = rho E_p (1 - n.up) / 2."""
    from aobake.ground import ALBEDO, Ground

    plane = Ground(2, -1.0)
    sun = Light.make("distant", "sun", (1, 2, 3), direction=(1.0, 0.0, 1.0))
    cos_l = 1.0 / math.sqrt(2.0)
    up = one_point((0.0, 0.0, 1.0))
    a = lit(up, [sun], n_indirect=64)
    b = lit(up, [sun], n_indirect=64, ground=plane)
    assert np.array_equal(a.direct, b.direct) and b.indirect[0].max() == 0.0
    side = one_point((1.0, 0.0, 0.0))
    r = lit(side, [sun], n_indirect=256, ground=plane)
    assert np.allclose(r.direct[0], np.array([1, 2, 3]) * cos_l)
    want = ALBEDO * np.array([1, 2, 3]) * cos_l / 2.0
    assert np.all(np.abs(r.indirect[0] - want) <= r.error[0] + 1e-3 * want)
    assert r.indirect[0] == pytest.approx(want, rel=0.03)
    assert lit(side, [sun], n_indirect=256).indirect[0].max() == 0.0  # nothing else reflects


def test_ground_hides_a_light_below_it_unless_shadows_are_off():
    from aobake.ground import Ground

    down = one_point((0.0, 0.0, -1.0))
    lamp = Light.make("point", "lamp", (4, 4, 4), position=(0.0, 0.0, -2.0))
    assert np.allclose(lit(down, [lamp]).direct[0], 1.0)  # I / d^2, d = 2
    hidden = lit(down, [lamp], ground=Ground(2, -1.0), bounces=2, n_indirect=16)
    assert hidden.irradiance[0].max() == 0.0 and hidden.n_shadow_rays == 3
    no_shadow = Light.make("point", "lamp", (4, 4, 4), position=(0.0, 0.0, -2.0), shadow=False)
    assert np.allclose(lit(down, [no_shadow], ground=Ground(2, -1.0), bounces=0).direct[0], 1.0)


def test_ground_under_a_wall_vertex_on_it():
    """A vertex on the plane facing sideways under a uniform dome: half its hemisphere
    sees the dome, pi L / 2; one bounce adds the plane's rho pi L over the other half."""
    from aobake.ground import ALBEDO, Ground

    wall = one_point((1.0, 0.0, 0.0))
    sky = Light.make("dome", "sky", (1.0, 1.0, 1.0))
    r = lit(wall, [sky], n_indirect=256, bounces=1, ground=Ground(2, 0.0))
    assert r.direct[0] == pytest.approx(np.full(3, math.pi / 2), rel=0.02)
    assert r.indirect[0] == pytest.approx(np.full(3, ALBEDO * math.pi / 2), rel=0.02)


def test_ground_under_a_vertex_in_it_below_a_small_disk():
    """A vertex lying in the plane, facing up under a coaxial disk of radius a at height
    h, dome L: E = pi L (1 - a^2 / (a^2 + h^2)) with or without the plane (it sees none
    of it, and its rays start on it)."""
    from aobake.ground import Ground

    a, h, k = 0.5, 1.0, 64
    angles = np.arange(k) * 2 * math.pi / k
    ring = np.stack([a * np.cos(angles), a * np.sin(angles), np.full(k, h)], axis=1)
    floor = np.array([[0.0, 0.0, 0.0], [1e-4, 0.0, 0.0], [0.0, 1e-4, 0.0]])
    pos = np.vstack([floor, [[0.0, 0.0, h]], ring])
    fan = np.array([[3, 4 + (i + 1) % k, 4 + i] for i in range(k)])
    normals = np.vstack([np.tile([0.0, 0.0, 1.0], (3, 1)), np.tile([0.0, 0.0, -1.0], (k + 1, 1))])
    surface = surface_from_arrays(pos, np.vstack([[[0, 1, 2]], fan]), normals)
    sky = Light.make("dome", "sky", (1.0, 1.0, 1.0))
    a_eff2 = a * a * k / (2 * math.pi) * math.sin(2 * math.pi / k)  # the polygon's area / pi
    want = math.pi * (1.0 - a_eff2 / (a_eff2 + h * h))
    for ground in (None, Ground(2, 0.0)):
        r = lit(surface, [sky], n_indirect=1024, bounces=0, ground=ground)
        assert r.direct[0, 0] == pytest.approx(want, rel=0.01)


def test_ground_leaves_a_modelled_floor_in_it_its_albedo():
    """A floor modelled in the plane keeps its hits (and its albedo, 0.8 here): a
    receiver above it facing down gets the same light with the plane as without, but
    for the few paths that pass the floor's edge and now meet the lit plane."""
    from dataclasses import replace

    from aobake.ground import Ground

    pos, faces = ground_grid(50.0, 2)
    receiver = np.array([[0.0, 0.0, 1.0], [1e-4, 0.0, 1.0], [0.0, 1e-4, 1.0]])
    normals = np.vstack([np.tile([0.0, 0.0, 1.0], (len(pos), 1)), np.tile([0.0, 0.0, -1.0], (3, 1))])
    surface = surface_from_arrays(np.vstack([pos, receiver]), np.vstack([faces, [[len(pos), len(pos) + 2, len(pos) + 1]]]), normals)
    sun = Light.make("distant", "sun", (1.0, 1.0, 1.0), direction=(0.0, 0.0, 1.0))
    shading = default_shading(surface.n_vertices, surface.n_faces, [sun])
    shading = replace(shading, face_albedo=np.full((surface.n_faces, 3), 0.8))
    a = irradiance(surface, shading, n_indirect=256)
    b = irradiance(surface, shading, n_indirect=256, ground=Ground(2, 0.0))
    top = len(pos)
    assert a.indirect[top, 0] == pytest.approx(0.8, rel=0.02)  # the floor fills its view
    assert np.allclose(a.indirect[top:], b.indirect[top:], rtol=2e-3)  # (0.66 if the plane took its hits)
