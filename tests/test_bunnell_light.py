"""The disk method's light (aobake.methods.bunnell.light): the CLI writes it as for the
reference; closed forms of the exact lights and of an area light's transfer; the
closed-sphere furnace; the box against the ray-traced reference."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from aobake.cli import main
from aobake.errors import InputError
from aobake.ground import ALBEDO, Ground
from aobake.io import load_mesh, read_bake
from aobake.io.lights import read_shading
from aobake.mesh import surface_from_arrays
from aobake.methods.bunnell import BunnellOptions
from aobake.methods.bunnell.light import BRUTE_MAX_VERTICES, disk_light, prepare_light
from aobake.methods.bunnell.light import ground_grid as ground_grid_of
from aobake.methods.embree.light import irradiance
from aobake.shading import Light, Shading, default_shading
from aobake.testing.scenes import ground_grid, sphere

CORNELL = Path(__file__).resolve().parents[1] / "data" / "cornell_box.usda"
IRR = ("irradiance_r", "irradiance_g", "irradiance_b")


def _ply_columns(path, names):
    import plyfile

    v = plyfile.PlyData.read(str(path))["vertex"].data
    return np.stack([np.asarray(v[k], dtype=np.float64) for k in names], axis=1)


def test_cli_bakes_the_box_light_with_bunnell(runner, tmp_path):
    out = tmp_path / "lit.ply"
    r = runner.invoke(main, ["bake", str(CORNELL), "-o", str(out), "--method", "bunnell", "--split-irradiance", "--color"])
    assert r.exit_code == 0, (r.output, r.stderr, r.exception)
    assert "not baked" not in r.stderr
    assert "effects ao, direct, indirect" in r.stderr
    e = _ply_columns(out, IRR)
    d = _ply_columns(out, tuple(f"irradiance_direct_{c}" for c in "rgb"))
    i = _ply_columns(out, tuple(f"irradiance_indirect_{c}" for c in "rgb"))
    assert np.isfinite(e).all() and e.min() >= 0 and e.max() > 0
    assert np.allclose(e, d + i, rtol=1e-6, atol=1e-7)  # float32 columns
    assert i.max() > 0
    ao = read_bake(out)
    assert ao.min() >= 0 and ao.max() <= 1
    surface = load_mesh(CORNELL)
    shading = read_shading(CORNELL, surface)
    np.testing.assert_allclose(e, disk_light(surface, shading).irradiance, rtol=1e-6, atol=1e-7)
    # --near reaches the light's near field: 0 = disks only
    r = runner.invoke(main, ["bake", str(CORNELL), "-o", str(out), "--method", "bunnell", "--near", "0"])
    assert r.exit_code == 0, (r.output, r.stderr, r.exception)
    disks = disk_light(surface, shading, near=0.0).irradiance
    np.testing.assert_allclose(_ply_columns(out, IRR), disks, rtol=1e-6, atol=1e-7)
    assert np.abs(disks - e).max() > 0.01 * e.max()
    # the reference's ray options are not the disk method's
    r = runner.invoke(main, ["bake", str(CORNELL), "-o", str(out), "--method", "bunnell", "--light-samples", "4"])
    assert r.exit_code == 2 and "--light-samples does not apply to --method bunnell" in r.output + r.stderr


def _grid(half=1.0, cells=4):
    pos, faces = ground_grid(half, cells)
    return surface_from_arrays(pos, faces)


def _lit(surface, lights, **kw):
    return disk_light(surface, default_shading(surface.n_vertices, surface.n_faces, lights), **kw)


def test_distant_and_point_lights_on_an_open_plane_are_exact():
    """One shadow ray a light and vertex: E = E_perp cos and I cos / d^2; the plane's own
    disks are edge-on to each other, so nothing bounces."""
    s = _grid()
    sun = Light.make("distant", "sun", (2.0, 1.0, 0.5), direction=(1.0, 0.0, 1.0))
    r = _lit(s, [sun])
    assert r.n_shadow_rays == s.n_vertices
    np.testing.assert_allclose(r.direct, np.tile([2.0, 1.0, 0.5], (s.n_vertices, 1)) / math.sqrt(2), rtol=1e-12)
    assert np.all(r.indirect == 0) and r.negative == 0 and np.all(r.error == 0)
    lamp = Light.make("point", "lamp", (3.0, 3.0, 3.0), position=(0.3, -0.2, 0.8))
    r = _lit(s, [lamp])
    d = np.array([0.3, -0.2, 0.8]) - s.positions
    want = 3.0 * d[:, 2] / np.linalg.norm(d, axis=1) ** 3
    np.testing.assert_allclose(r.direct[:, 0], want, rtol=1e-12)


def test_disk_light_on_its_axis_meets_the_closed_form():
    """The centre vertex under a coaxial disk light: E = pi L R^2 / (R^2 + h^2) (the
    light cut into LIGHT_DISKS disks: within 1%); it casts no shadow ray."""
    s = _grid(1.0, 4)
    radius, h, value = 0.4, 0.5, 2.0
    disk = Light.make("disk", "d", (value,) * 3, position=(0.0, 0.0, h), normal=(0.0, 0.0, -1.0), radius=radius)
    r = _lit(s, [disk])
    centre = int(np.argmin(np.linalg.norm(s.positions, axis=1)))
    want = math.pi * value * radius**2 / (radius**2 + h**2)
    assert r.direct[centre, 0] == pytest.approx(want, rel=0.01)
    assert r.n_shadow_rays == 0 and r.negative == 0


@pytest.mark.parametrize("bounces", [1, 3])
def test_furnace_inside_a_closed_sphere(bounces):
    """A closed sphere emitting L_e with albedo rho: direct pi L_e and each bounce k adds
    (rho s)^k of it, s the share of the enclosure the vertex disks see (the disk sum:
    0.95 at 162 vertices, 0.99 at 642); never more: no energy gained."""
    rho, le = 0.6, 2.0
    s = sphere(1.0, 2, inward=True)
    m, n = s.n_faces, s.n_vertices
    sh = Shading((), np.full((m, 3), rho), np.full((m, 3), le), np.full((n, 3), rho), np.full((n, 3), le))
    r = disk_light(s, sh, bounces=bounces)
    one = disk_light(s, sh, bounces=1)
    full = math.pi * le
    assert np.all(r.direct <= full) and r.direct.min() > 0.96 * full
    share = one.indirect.mean() / (rho * one.direct.mean())
    assert 0.93 < share <= 1.0
    want = r.direct.mean() * sum((rho * share) ** k for k in range(1, bounces + 1))
    assert r.indirect.mean() == pytest.approx(want, rel=0.01)
    assert r.irradiance.max() <= full * sum(rho**k for k in range(bounces + 1))
    assert r.negative == 0


def test_the_box_against_the_ray_traced_reference():
    """The bundled box (RectLight, one bounce) at the defaults: relative RMSE of the
    irradiance within the goal, 0.08, of a 256-sample reference (0.044 against 4,096
    samples and 16,384 paths, docs/bunnell-light.md); finite and non-negative, the same
    on two threads."""
    surface = load_mesh(CORNELL)
    shading = read_shading(CORNELL, surface)
    ref = irradiance(surface, shading, n_samples=256, n_indirect=256, seed=3)
    r = disk_light(surface, shading)
    e, e_ref = r.irradiance, ref.irradiance
    assert np.isfinite(e).all() and e.min() >= 0
    assert math.sqrt(((e - e_ref) ** 2).sum() / (e_ref**2).sum()) < 0.08
    again = disk_light(surface, shading, BunnellOptions(threads=2))  # the default is one thread below SERIAL_VERTICES
    assert np.array_equal(again.irradiance, e)


def test_max_distance_caps_the_transfer_and_the_shadow_passes():
    """--max-distance D on the box (extent 1): geometry farther than D neither reflects
    nor occludes. Every cluster opened equals the brute-force passes with D (float32
    lists: 1e-6 of the peak); D past the scene changes nothing, bit for bit; D = 0.5
    moves the result toward the reference with the same D (0.11 against 0.19 without it,
    docs/bunnell-light.md; vertices buried under the blocks hold most of what is left)."""
    surface = load_mesh(CORNELL)
    shading = read_shading(CORNELL, surface)
    capped = BunnellOptions(max_distance=0.5)
    brute = disk_light(surface, shading, capped, theta=None, near=0.0)
    opened = disk_light(surface, shading, capped, theta=math.inf, aimed_theta=math.inf, share=False, near=0.0)
    peak = brute.irradiance.max()
    assert np.abs(opened.direct - brute.direct).max() < 1e-6 * peak
    assert np.abs(opened.indirect - brute.indirect).max() < 1e-6 * peak
    free = disk_light(surface, shading)
    assert np.array_equal(disk_light(surface, shading, BunnellOptions(max_distance=10.0)).irradiance, free.irradiance)
    e = disk_light(surface, shading, capped).irradiance
    ref = irradiance(surface, shading, n_samples=256, n_indirect=256, seed=3, max_distance=0.5).irradiance
    rel = lambda a: math.sqrt(((a - ref) ** 2).sum() / (ref**2).sum())  # noqa: E731
    assert rel(e) < 0.15 and rel(free.irradiance) > rel(e) + 0.05


@pytest.mark.parametrize("near", [-1.0, math.nan, math.inf])
def test_near_field_reach_must_be_finite_and_non_negative(near):
    s = _grid()
    with pytest.raises(ValueError, match="near must be finite"):
        _lit(s, [Light.make("distant", "sun", (1.0, 1.0, 1.0), direction=(0.0, 0.0, 1.0))], near=near)


def test_large_meshes_bake_through_the_trees(monkeypatch):
    """Past the brute-force limit through the trees (a 20,449-vertex plane under a distant
    light: E_perp cos exact, nothing bounces); the brute-force passes refuse it; past the
    memory limit, one line naming the file."""
    s = _grid(1.0, 142)
    assert s.n_vertices > BRUTE_MAX_VERTICES
    sun = Light.make("distant", "sun", (1.0, 1.0, 1.0), direction=(0.0, 1.0, 1.0))
    r = _lit(s, [sun])
    np.testing.assert_allclose(r.irradiance, np.full((s.n_vertices, 3), 1 / math.sqrt(2)), rtol=1e-12)
    with pytest.raises(ValueError, match="at most 20,000"):
        _lit(s, [sun], theta=None)
    import aobake.methods.bunnell.light as disk

    monkeypatch.setattr(disk, "MAX_VERTICES", 20_000)
    with pytest.raises(InputError, match="at most 20,000 ") as err:
        _lit(s, [sun])
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("knobs", [{}, {"faces_occlude": False}])
def test_the_trees_with_every_cluster_opened_are_the_brute_force_passes(knobs):
    """The box (RectLight, one bounce): theta = inf (trees of the bounce, the shadow
    subtraction and the aimed pass, every cluster opened, no shared passes) equals the brute-force passes
    (float32 lists in the transfer walk: 1e-6 of the peak); at the defaults within 1% of
    them (relative RMSE). Both without the triangles' near field, which the brute-force
    passes do not have (tested against subdivided triangles below)."""
    surface = load_mesh(CORNELL)
    shading = read_shading(CORNELL, surface)
    brute = disk_light(surface, shading, theta=None, **knobs)
    opened = disk_light(surface, shading, theta=math.inf, aimed_theta=math.inf, share=False, near=0.0, **knobs)
    peak = brute.irradiance.max()
    assert np.abs(opened.direct - brute.direct).max() < 1e-6 * peak
    assert np.abs(opened.indirect - brute.indirect).max() < 1e-6 * peak
    assert brute.indirect.max() > 0.01 * peak
    if not knobs:
        tree = disk_light(surface, shading, near=0.0)
        e, e_ref = tree.irradiance, brute.irradiance
        assert math.sqrt(((e - e_ref) ** 2).sum() / (e_ref**2).sum()) < 0.01


def test_dome_is_the_disk_ao_times_pi_l():
    """A dome gives pi L (1 - A), A the disk method's cosine occlusion: pi L on an open
    plane, and under the box's ceiling as much less as the AO says."""
    s = _grid()
    dome = Light.make("dome", "sky", (0.5, 1.0, 2.0))
    r = _lit(s, [dome], bounces=0)
    np.testing.assert_allclose(r.direct, np.tile(math.pi * np.array([0.5, 1.0, 2.0]), (s.n_vertices, 1)), rtol=1e-12)
    box = load_mesh(CORNELL)
    r = _lit(box, [dome], bounces=0)
    from aobake.methods.bunnell import bunnell_ao

    ao = bunnell_ao(box, measure="cosine")
    np.testing.assert_allclose(r.direct[:, 1], math.pi * ao, rtol=1e-12)
    assert ao.min() < 0.5 < ao.max()


def test_ground_occludes_the_shadow_rays():
    """A wall facing +x standing on z = 1 and a point light in front of it, below a
    ground plane at z = 0.8: no light reaches; without the plane, I cos / d^2."""
    pos, faces = ground_grid(1.0, 4)
    wall = np.column_stack([np.zeros(len(pos)), pos[:, 0], pos[:, 1] + 2.0])  # x = 0, z in [1, 3]
    s = surface_from_arrays(wall, faces, np.tile([1.0, 0.0, 0.0], (len(pos), 1)))
    lamp = Light.make("point", "lamp", (4.0, 4.0, 4.0), position=(1.0, 0.0, 0.5))
    r = _lit(s, [lamp], ground=Ground(2, 0.8), bounces=0)
    assert np.all(r.direct == 0) and r.n_shadow_rays == s.n_vertices
    r = _lit(s, [lamp])
    d = np.array([1.0, 0.0, 0.5]) - s.positions
    np.testing.assert_allclose(r.direct[:, 0], 4.0 * d[:, 0] / np.linalg.norm(d, axis=1) ** 3, rtol=1e-12)


def test_ground_reflects_as_the_closed_form_and_the_reference():
    """--ground with bounces: the plane reflects (albedo ALBEDO) through a grid of ground
    elements. A small vertical plate at height 0.5 under a distant light gets
    rho E_perp (l.up) / 2 from it (the reference's closed form: within 2%; the grid's reach
    is finite); a sphere resting on the plane is within 2% of the reference with the same
    plane (relative RMSE; 16% without the reflection), and the same with Y up. Without
    bounces there is no grid: the same bits as a plane that only occludes."""
    h, a = 0.5, 0.01
    plate = np.array([[0, -a, h - a], [0, a, h - a], [0, a, h + a], [0, -a, h + a]], dtype=float)
    s = surface_from_arrays(plate, np.array([[0, 2, 1], [0, 3, 2]]))  # facing -x
    ground = Ground(2, 0.0)
    for d in ((0.3, 0.0, 1.0), (-0.5, 0.4, 1.0)):
        sun = Light.make("distant", "sun", (1.0, 2.0, 3.0), direction=d)
        r = _lit(s, [sun], ground=ground)
        l_up = d[2] / np.linalg.norm(d)
        want = ALBEDO * np.array([1.0, 2.0, 3.0]) * l_up / 2
        np.testing.assert_allclose(r.indirect, np.tile(want, (4, 1)), rtol=0.02)
        assert r.irradiance.shape == (4, 3)  # the plate's vertices alone
    ball = sphere(0.5, 3)
    ball = surface_from_arrays(ball.positions + np.array([0.0, 0.0, 0.5]), ball.faces)
    sun = Light.make("distant", "sun", (3.0, 3.0, 3.0), direction=(0.3, 0.2, 1.0))
    shading = default_shading(ball.n_vertices, ball.n_faces, [sun])
    ref = irradiance(ball, shading, n_samples=64, n_indirect=2048, seed=3, ground=ground).irradiance
    rel = lambda e: math.sqrt(((e - ref) ** 2).sum() / (ref**2).sum())  # noqa: E731
    assert rel(disk_light(ball, shading, ground=ground).irradiance) < 0.02
    z_up = disk_light(ball, shading, ground=ground).irradiance
    ball_y = surface_from_arrays(ball.positions[:, [1, 2, 0]], ball.faces)  # the same scene, Y up
    sun_y = Light.make("distant", "sun", (3.0, 3.0, 3.0), direction=(0.2, 1.0, 0.3))
    y_up = disk_light(ball_y, default_shading(ball.n_vertices, ball.n_faces, [sun_y]), ground=Ground(1, 0.0)).irradiance
    assert np.abs(y_up - z_up).max() < 2e-3 * z_up.max()  # the grid's diagonals differ
    occluding = prepare_light(ball, shading, ground=ground, ground_reflects=False)
    assert rel(occluding.light().irradiance) > 0.1
    direct = disk_light(ball, shading, ground=ground, bounces=0)
    assert np.array_equal(direct.irradiance, occluding.light(bounces=0).irradiance)
    # under a dome: the ball's own AO is taken without the grid (its direct light the
    # plane-only bake's bits); the grid's points see the sky past the ball
    sky = default_shading(ball.n_vertices, ball.n_faces, [Light.make("dome", "sky", (1.0, 1.0, 1.0))])
    r = disk_light(ball, sky, ground=ground)
    assert np.array_equal(r.direct, prepare_light(ball, sky, ground=ground, ground_reflects=False).light().direct)
    ref = irradiance(ball, sky, n_samples=64, n_indirect=1024, seed=3, ground=ground).irradiance
    assert math.sqrt(((r.irradiance - ref) ** 2).sum() / (ref**2).sum()) < 0.02


def test_cli_bakes_the_box_light_with_bunnell_on_a_reflecting_ground(runner, tmp_path):
    """`bake --method bunnell --ground auto` on the box (Y up, its floor in the plane): the
    irradiance is disk_light's with that plane, reflecting, and no warning says it does not."""
    from aobake.ground import resolve_ground

    out = tmp_path / "lit.ply"
    r = runner.invoke(main, ["bake", str(CORNELL), "-o", str(out), "--method", "bunnell", "--ground", "auto"])
    assert r.exit_code == 0, (r.output, r.stderr, r.exception)
    assert "does not bounce" not in r.stderr
    surface = load_mesh(CORNELL)
    shading = read_shading(CORNELL, surface)
    plane = resolve_ground("auto", surface.positions, "Y")
    want = disk_light(surface, shading, ground=plane).irradiance
    np.testing.assert_allclose(_ply_columns(out, IRR), want, rtol=1e-6, atol=1e-7)
    assert np.abs(want - disk_light(surface, shading).irradiance).max() > 1e-3 * want.max()  # the open front sees it


def test_a_floor_modelled_in_the_reflecting_plane_keeps_its_own():
    """A ball on a floor modelled in the --ground plane: the grid has a hole under the floor
    (the reference's plane reflects only where the mesh has nothing); the shadow rays trace
    the input alone, so its direct light is the plane-only bake's, bit for bit; the whole
    within 2% of the reference (relative RMSE; 2.9% with the plane only occluding)."""
    ball = sphere(0.5, 3)
    floor_pos, floor_faces = ground_grid(1.5, 24)
    s = surface_from_arrays(np.concatenate([ball.positions + [0.0, 0.0, 0.5], floor_pos]),
                            np.concatenate([ball.faces, floor_faces + ball.n_vertices]))  # fmt: skip
    ground = Ground(2, 0.0)
    shading = default_shading(s.n_vertices, s.n_faces, [Light.make("distant", "sun", (3.0,) * 3, direction=(0.3, 0.2, 1.0))])
    joined, extended = ground_grid_of(s, shading, ground)
    grid = joined.faces[s.n_faces :]
    inside = np.all(np.abs(joined.positions[grid][:, :, :2]) < 1.5, axis=(1, 2))
    assert len(grid) < 2 * 80 * 80 and not inside.any()  # no grid triangle under the floor
    assert np.array_equal(joined.positions[: s.n_vertices], s.positions) and np.array_equal(joined.faces[: s.n_faces], s.faces)
    r = disk_light(s, shading, ground=ground)
    plane = prepare_light(s, shading, ground=ground, ground_reflects=False).light()
    assert np.array_equal(r.direct, plane.direct)
    ref = irradiance(s, shading, n_samples=64, n_indirect=2048, seed=3, ground=ground).irradiance
    assert math.sqrt(((r.irradiance - ref) ** 2).sum() / (ref**2).sum()) < 0.02


def test_a_distant_light_with_an_angle_is_taken_along_its_axis():
    s = _grid()
    sun = Light.make("distant", "sun", (2.0, 2.0, 2.0), direction=(0.0, 0.0, 1.0), angle=0.2)
    r = _lit(s, [sun])
    np.testing.assert_allclose(r.direct, 2.0, rtol=1e-12)
    assert r.n_shadow_rays == s.n_vertices


def test_plan_for_bunnell_casts_no_ray_for_an_area_light(runner):
    r = runner.invoke(main, ["plan", str(CORNELL), "--method", "bunnell"])
    assert r.exit_code == 0, (r.output, r.exception)
    assert "yes direct" in r.stdout and "yes indirect" in r.stdout
    assert "/World/light (rect): 733 receivers in reach, 0 shadow rays" in r.stdout
    assert "expected rays: none" in r.stdout


def test_negative_light_is_counted_measured_and_reported():
    """The bounce's shadow passes take some of the box's vertices below zero: counted,
    their negative parts' magnitude summed (the clamp's addition to the irradiance), and
    the warning says both; without shadow passes nothing goes negative."""
    import warnings

    from aobake.methods.bunnell.light import run_light

    surface = load_mesh(CORNELL)
    shading = read_shading(CORNELL, surface)
    open_ = disk_light(surface, shading, shadow_passes=0)
    assert open_.negative == 0 and open_.clipped == 0.0
    one = disk_light(surface, shading, bounces=1)
    assert one.negative > 0 and 0 < one.clipped < 0.05 * one.irradiance.sum()
    direct_only = disk_light(surface, shading, bounces=0)
    assert direct_only.negative == 0 and direct_only.clipped == 0.0  # the aimed passes never go negative
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        r = run_light(surface, shading, BunnellOptions())
    assert r.negative == one.negative and r.clipped == one.clipped
    (w,) = [str(c.message) for c in caught if "below zero" in str(c.message)]
    share = one.clipped / one.irradiance.sum()
    assert f"{one.negative:,} of {surface.n_vertices:,} vertices" in w and f"added {share:.2%}" in w
