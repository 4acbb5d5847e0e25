"""The ground plane (``--ground auto|HEIGHT``): its closed forms against quadrature, Embree's
one-test-per-ray plane against an explicit plane of triangles, the disk method against
Embree, the plane's bad values, and what the outputs record."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from aobake.cli import main
from aobake.errors import InputError
from aobake.ground import Ground, parse_ground, plane_occlusion, resolve_ground
from aobake.mesh import surface_from_arrays
from aobake.methods.bunnell import bunnell_ao
from aobake.methods.embree import embree_ao
from aobake.pipeline import bake, bake_file, bake_part

RAYS = 512


def _sphere(lift: float = 1.0, subdivisions: int = 2, up: int = 1):
    """A unit icosphere resting on the plane x[up] = 0 (its lowest vertex at lift - 1)."""
    s = trimesh.creation.icosphere(subdivisions)
    v = np.asarray(s.vertices, dtype=np.float64)
    p = v.copy()
    p[:, up] += lift
    return surface_from_arrays(p, np.asarray(s.faces), v)


def _with_floor(surface, half: float, height: float = 0.0):
    """``surface`` plus a square of two triangles (half-size ``half``) at y = height, facing +y."""
    n = surface.n_vertices
    quad = np.array([[-half, height, -half], [half, height, -half], [half, height, half], [-half, height, half]])
    faces = np.array([[0, 2, 1], [0, 3, 2]]) + n
    normals = np.vstack([surface.normals, np.tile([0.0, 1.0, 0.0], (4, 1))])
    return surface_from_arrays(
        np.vstack([surface.positions, quad]), np.vstack([surface.faces, faces]), normals
    )


def _directions(k: int = 200_000) -> np.ndarray:
    """k nearly uniform unit directions (a Fibonacci sphere): an independent quadrature."""
    i = np.arange(k) + 0.5
    z = 1.0 - 2.0 * i / k
    phi = math.pi * (1.0 + 5**0.5) * i
    r = np.sqrt(1.0 - z * z)
    return np.c_[r * np.cos(phi), r * np.sin(phi), z]


@pytest.mark.parametrize("measure", ["cosine", "uniform"])
@pytest.mark.parametrize("reach", [None, 2.0])
def test_closed_forms_match_quadrature(measure, reach):
    d = _directions()
    rng = np.random.default_rng(3)
    normals = rng.normal(size=(12, 3))
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    normals[0] = [0, 1, 0]
    normals[1] = [0, -1, 0]
    normals[2] = [1, 0, 0]
    heights = rng.uniform(0.0, 2.5, size=12)
    heights[:3] = [0.0, 0.5, 1.0]
    got = plane_occlusion(heights, normals, 1, measure, reach)
    for n, h, a in zip(normals, heights, got, strict=True):
        down = -d[:, 1]
        hits = down > 0 if reach is None else down * reach > h
        cos = d @ n
        front = cos > 0
        if measure == "cosine":  # 1/pi int V cos dw = 4 mean(V cos) over the sphere
            want = 4.0 * np.mean(np.where(front & hits, cos, 0.0))
        else:
            want = 2.0 * np.mean(front & hits)
        assert a == pytest.approx(want, abs=2e-3)


def test_closed_form_values():
    """(1 - n.up)/2 unbounded (cosine); acos(n.up)/pi (uniform); a zero normal: the sphere's half."""
    n = np.array([[0, 1.0, 0], [1.0, 0, 0], [0, -1.0, 0], [0, 0, 0]])
    h = np.zeros(4)
    assert plane_occlusion(h, n, 1) == pytest.approx([0.0, 0.5, 1.0, 0.5])
    assert plane_occlusion(h, n, 1, "uniform") == pytest.approx([0.0, 0.5, 1.0, 0.5])
    # a point 1 above, looking down, reach 2: a cap of half-angle 60 degrees: sin^2 = 3/4
    assert plane_occlusion([1.0], [[0, -1.0, 0]], 1, "cosine", 2.0) == pytest.approx([0.75])
    assert plane_occlusion([3.0], [[0, -1.0, 0]], 1, "cosine", 2.0) == pytest.approx([0.0])


@pytest.mark.parametrize("reach", [None, 0.75])
def test_embree_plane_equals_an_explicit_plane(reach):
    """Same rays (same seed, same vertex indices): the analytic plane and two triangles
    agree wherever the triangles reach (unbounded: a plane 400 radii wide; directions
    past its edge are a cosine measure below 1e-3)."""
    s = _sphere(1.0)
    g = resolve_ground("auto", s.positions, "Y")
    a = embree_ao(s, n_rays=RAYS, ground=g, max_distance=reach).ao
    b = embree_ao(_with_floor(s, 200.0, g.height), n_rays=RAYS, max_distance=reach).ao[: s.n_vertices]
    tol = 3.0 / math.sqrt(RAYS)  # one vertex's sampling error, a generous bound
    assert np.abs(a - b).max() < tol
    assert abs(np.mean(a - b)) < 0.004
    # and both equal the closed form (a convex sphere occludes nothing of itself)
    want = 1.0 - plane_occlusion(g.heights(s.positions), s.normals, 1, "cosine", reach)
    assert np.sqrt(np.mean((a - want) ** 2)) < 0.01


def test_bit_identical_without_ground_and_ground_only_adds_occlusion():
    s = _sphere(1.0)
    ref = embree_ao(s, n_rays=64).ao
    assert np.array_equal(embree_ao(s, n_rays=64, ground=None).ao, ref)
    assert np.array_equal(bake(s, n_rays=64), ref)
    with_plane = bake(s, n_rays=64, ground="auto")
    assert (with_plane <= ref).all() and (with_plane < ref).any()
    assert np.array_equal(bunnell_ao(s, ground=None), bunnell_ao(s))


def test_vertices_on_the_plane_are_neither_nan_nor_black():
    """A wall standing on the plane (auto): every vertex sees half its hemisphere below
    the horizon, 0.5 for the cosine measure, its bottom edge included; a floor lying on
    the plane sees none of it."""
    wall = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.0]])
    floor = np.array([[0, 0, 1], [1, 0, 1], [1, 0, 2], [0, 0, 2.0]])
    up = np.tile([0, 0, 1.0], (4, 1))
    for points, faces, normals, want in (
        (wall, [[0, 1, 2], [0, 2, 3]], up, 0.5),
        (floor, [[0, 2, 1], [0, 3, 2]], np.tile([0, 1.0, 0], (4, 1)), 1.0),
    ):
        s = surface_from_arrays(points, np.array(faces), normals)
        for method, options in (("embree", {"n_rays": 256}), ("bunnell", {})):
            ao = bake(s, method, ground="auto", **options)
            assert np.isfinite(ao).all()
            assert ao == pytest.approx(want, abs=0.02 if want < 1 else 1e-12), method


def test_bunnell_with_ground_matches_the_closed_form_on_a_convex_body():
    s = _sphere(1.0, subdivisions=3)
    g = resolve_ground("auto", s.positions, "Y")
    for reach in (None, 0.75):
        want = 1.0 - plane_occlusion(g.heights(s.positions), s.normals, 1, "cosine", reach)
        got = bunnell_ao(s, ground=g, max_distance=reach)
        assert np.sqrt(np.mean((got - want) ** 2)) < 0.003


def _bunny():
    from pathlib import Path

    from aobake.io import load_mesh

    return load_mesh(Path(__file__).resolve().parents[1] / "data" / "bunny.ply")


@pytest.mark.parametrize("reach", [None, 0.5])
def test_bunnell_with_ground_against_embree(reach):
    """On the bunny resting on the plane (auto): within the disk method's error without a
    plane plus 0.003 (measured: 0.0067 and 0.0134 against 0.0058 and 0.0129)."""
    s = _bunny()
    g = resolve_ground("auto", s.positions, "Y")
    ref = embree_ao(s, n_rays=1024, ground=g, max_distance=reach).ao
    got = bunnell_ao(s, ground=g, max_distance=reach)
    plain = bunnell_ao(s, max_distance=reach)
    plain_ref = embree_ao(s, n_rays=1024, max_distance=reach).ao
    rmse = np.sqrt(np.mean((got - ref) ** 2))
    assert rmse < np.sqrt(np.mean((plain - plain_ref) ** 2)) + 0.003
    assert abs(np.mean(got - ref)) < 0.005
    # the plane counts: far from the plain bake where it occludes much
    assert np.sqrt(np.mean((plain - ref) ** 2)) > 3 * rmse


def test_bunnell_plane_under_a_floor_counts_once():
    """A sphere on a floor lying on the plane: the floor already blocks what the plane
    would, near the sphere; the bins must not count both (0.035 RMSE when they did)."""
    from aobake.testing import scenes

    s, _ = scenes.sphere_on_ground(0.5, 2, gap=0.0, cells=8)
    g = resolve_ground("auto", s.positions, "Z")
    ref = embree_ao(s, n_rays=1024, ground=g).ao
    got = bunnell_ao(s, ground=g)
    assert np.sqrt(np.mean((got - ref) ** 2)) < 0.012


def test_resolve_ground_auto_height_and_refusals():
    s = _sphere(1.0, up=2)
    assert resolve_ground("auto", s.positions, "Z") == Ground(2, float(s.positions[:, 2].min()))
    assert resolve_ground(-3.0, s.positions, "Z") == Ground(2, -3.0)
    assert resolve_ground(None, s.positions, "Z") is None
    with pytest.raises(InputError, match=r"--ground 3 is above the mesh's highest point 2 \(up Z\)"):
        resolve_ground(3.0, s.positions, "Z", "m.ply")
    with pytest.raises(InputError, match=r"above the mesh's lowest point 0 \(up Z\): \d+ vertices below"):
        resolve_ground(0.5, s.positions, "Z", "m.ply")
    # within float rounding of the lowest vertex: on it
    assert resolve_ground(1e-9, s.positions, "Z").height == 1e-9
    assert parse_ground(" AUTO ") == "auto"
    for bad in ("nan", "inf", "low", ""):
        with pytest.raises(ValueError):
            parse_ground(bad)


def _ply(tmp_path, surface, name="m.ply"):
    path = tmp_path / name
    trimesh.Trimesh(surface.positions, surface.faces, vertex_normals=surface.normals, process=False).export(path)
    return path


def test_cli_bad_ground_is_one_line_exit_2_and_writes_nothing(tmp_path, runner):
    src = _ply(tmp_path, _sphere(1.0))
    out = tmp_path / "o.ply"
    r = runner.invoke(main, ["bake", str(src), "-o", str(out), "--ground", "3", "-q"])
    assert r.exit_code == 2
    assert r.output.strip().splitlines() == [
        "Error: m.ply: --ground 3 is above the mesh's highest point 2 (up Y)"
    ]
    assert not out.exists() and list(tmp_path.iterdir()) == [src]
    r = runner.invoke(main, ["bake", str(src), "-o", str(out), "--ground", "1", "--method", "bunnell"])
    assert r.exit_code == 2 and "lowest point 0 (up Y)" in r.output and "Traceback" not in r.output
    r = runner.invoke(main, ["bake", str(src), "-o", str(out), "--ground", "nan"])
    assert r.exit_code == 2 and "--ground" in r.output
    assert not out.exists()


def test_outputs_record_the_ground_and_up_axis_decides_it(tmp_path, runner):
    from pxr import Usd

    from aobake.io import read_bake

    s = _sphere(1.0, up=2)
    src = _ply(tmp_path, s)
    ply, usd = tmp_path / "o.ply", tmp_path / "o.usda"
    r = runner.invoke(main, ["bake", str(src), "-o", str(ply), "-o", str(usd), "--rays", "16", "--ground", "auto",
                             "--up", "Z", "-q"])
    assert r.exit_code == 0, r.output
    low = float(s.positions[:, 2].min())
    assert f"comment aobake ground={low!r}" in ply.read_bytes().decode("latin-1")
    stage = Usd.Stage.Open(str(usd))
    data = [p.GetCustomData().get("aobake", {}) for p in stage.Traverse()]
    assert data and all(d.get("ground") == pytest.approx(low) for d in data)
    ao = read_bake(ply)
    want = bake(s, n_rays=16, ground=Ground(2, low))
    assert np.allclose(ao, want, atol=1e-6)
    # Y up (the default for a PLY without a comment): the plane under the lowest y instead
    r = runner.invoke(main, ["bake", str(src), "-o", str(tmp_path / "y.ply"), "--rays", "16", "--ground", "auto", "-q"])
    assert r.exit_code == 0
    assert not np.allclose(read_bake(tmp_path / "y.ply"), ao)


def test_split_and_weld_honour_the_ground(tmp_path):
    s = _sphere(1.0)
    src = _ply(tmp_path, s)
    whole = bake_file(src, tmp_path / "w.ply", n_rays=32, ground="auto")
    from aobake.io import read_bake

    full = read_bake(tmp_path / "w.ply")
    parts = [bake_part(src, parts=(k, 3), n_rays=32, ground="auto").ao for k in range(3)]
    assert np.array_equal(np.concatenate(parts), full)
    assert whole.n_vertices == s.n_vertices
    # welded: other sample keys, the same plane (its mean within the sampling error)
    bake_file(src, tmp_path / "weld.ply", n_rays=32, ground="auto", weld=True)
    bake_file(src, tmp_path / "weld0.ply", n_rays=32, weld=True)
    welded, open_ = read_bake(tmp_path / "weld.ply"), read_bake(tmp_path / "weld0.ply")
    assert abs(np.mean(welded - full)) < 0.02 and np.mean(open_ - welded) > 0.2


def test_batch_passes_the_ground_on(tmp_path):
    from aobake.batch import Settings, emit_commands, settings_key

    src = _ply(tmp_path, _sphere(1.0))
    plain, _ = settings_key(Settings(), ["ply"])
    assert "ground" not in plain  # earlier manifests keep their keys
    described, key = settings_key(Settings(ground="auto"), ["ply"])
    assert described["ground"] == "auto" and key != settings_key(Settings(ground=0.0), ["ply"])[1]
    lines = list(emit_commands([str(src)], tmp_path / "out", formats=("ply",), settings=Settings(ground=-0.5)))
    assert len(lines) == 1 and "--ground -0.5" in lines[0]


def test_fields_multiply_into_the_bake_with_its_ground(tmp_path):
    """A field is one more occluder: its 1 - A_k multiplies the mesh's own AO, which
    holds the plane (a convex receiver's own AO is the plane's alone)."""
    from aobake.io import read_bake
    from aobake.methods.fields import fit_field

    occluder = _sphere(0.0, subdivisions=1)
    f = fit_field(occluder, resolution=4, radial_samples=8)
    src = _ply(tmp_path, _sphere(1.0))
    placed = [(f, (2.2, 1.0, 0.0))]
    for name, kw in (("g", {"ground": "auto"}), ("f", {"fields": placed}), ("gf", {"ground": "auto", "fields": placed})):
        bake_file(src, tmp_path / f"{name}.ply", n_rays=64, **kw)
    g, fo, gf = (read_bake(tmp_path / f"{n}.ply") for n in ("g", "f", "gf"))
    assert (fo < 1).any() and (g < 1).any()
    np.testing.assert_allclose(gf, g * fo, atol=1e-6)  # the sphere's own AO without either is 1


def test_bunnell_ground_in_every_pass_path_and_measure():
    """The exact sum, later passes (bins kept by every receiver), the uniform measure and
    the plain sums (no bins: the plane added) all count the plane."""
    from aobake.methods.bunnell import estimate
    from aobake.methods.bunnell.options import BunnellOptions

    s = _bunny()
    g = resolve_ground("auto", s.positions, "Y")
    one = bunnell_ao(s, ground=g)
    two = bunnell_ao(s, ground=g, passes=2)
    assert np.sqrt(np.mean((two - one) ** 2)) < 0.003
    # every cluster opened: the exact sum's terms; the exact sum bins every receiver, the
    # tree pass only those whose sums fill a bin (the others take P (1 - T))
    tree = bunnell_ao(s, ground=g, theta=1e6)
    exact = estimate(s, BunnellOptions(), exact=True, ground=g)
    assert np.sqrt(np.mean((tree - exact) ** 2)) < 0.004
    ref = embree_ao(s, n_rays=1024, ground=g, measure="uniform").ao
    got = bunnell_ao(s, ground=g, measure="uniform")
    plain_err = np.sqrt(np.mean((bunnell_ao(s, measure="uniform") - embree_ao(s, n_rays=1024, measure="uniform").ao) ** 2))
    assert np.sqrt(np.mean((got - ref) ** 2)) < plain_err + 0.01
    ref = embree_ao(s, n_rays=1024, ground=g).ao
    plain = bunnell_ao(s, ground=g, directional=False)
    assert np.sqrt(np.mean((plain - ref) ** 2)) < 0.03


def test_a_vertex_without_a_normal_sees_half_the_sphere_blocked():
    """An unreferenced vertex (no normal) samples the whole sphere: the plane is half of it."""
    s = _sphere(1.0, subdivisions=1)
    lone = np.vstack([s.positions, [[5.0, 0.5, 0.0]]])
    t = surface_from_arrays(lone, s.faces)
    assert not t.normals[-1].any()
    g = resolve_ground("auto", t.positions, "Y")
    e = embree_ao(t, n_rays=1024, ground=g).ao[-1]
    b = bunnell_ao(t, ground=g)[-1]
    assert e == pytest.approx(0.5, abs=0.03)
    assert b == pytest.approx(0.5, abs=0.03)


def test_bent_normals_see_the_plane():
    """A wall on the plane: only the upper half of its hemisphere escapes, so its bent
    normal is that half's cosine-weighted mean direction, (0, 4 / (3 pi), 2 / 3) with n
    = z (E[sin theta] = E[cos theta] = 2/3, E[sin phi | up] = 2 / pi); alone it is n."""
    wall = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.0]])
    s = surface_from_arrays(wall, np.array([[0, 1, 2], [0, 2, 3]]), np.tile([0, 0, 1.0], (4, 1)))
    g = resolve_ground("auto", s.positions, "Y")
    free = embree_ao(s, n_rays=1024, bent_normals=True).bent_normals
    bent = embree_ao(s, n_rays=1024, bent_normals=True, ground=g).bent_normals
    assert np.allclose(free, [0, 0, 1], atol=0.02)  # nothing blocks the wall alone
    assert (bent[:, 1] > 0.3).all() and np.allclose(np.linalg.norm(bent, axis=1), 1.0)
    want = np.array([0.0, 4.0 / (3.0 * math.pi), 2.0 / 3.0])
    assert np.allclose(bent, want / np.linalg.norm(want), atol=0.03)


def test_plane_bins_split_the_closed_form_as_the_direction_bins_do():
    """Each of the 16 direction bins (azimuth sector of the receiver's tangent frame x
    band at 45 degrees) gets the plane's measure inside it: against a quadrature over
    directions binned the same way, and summing to the closed form."""
    from aobake.kernels import bunnell as kb
    from aobake.kernels.warps import frame

    d = _directions(400_000)
    rng = np.random.default_rng(7)
    normals = rng.normal(size=(6, 3))
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    normals[0] = [0.0, -1.0, 0.0]
    for ca in (0.0, 0.4):
        out = np.zeros((6, 16))
        kb.plane_bins(normals, np.full(6, ca), 1, out)
        exact = plane_occlusion(np.full(6, ca), normals, 1, "cosine", 1.0)
        assert np.abs(out.sum(axis=1) - exact).max() < 0.01  # measured 0.0055
        for n, got in zip(normals, out, strict=True):
            tx, ty, tz, bx, by, bz = frame(*n)
            x, y, z = d @ [tx, ty, tz], d @ [bx, by, bz], d @ n
            sector = (np.floor(np.mod(np.arctan2(y, x), 2 * np.pi) / (np.pi / 4))).astype(int) % 8
            band = np.where(z * z > 0.5, 0, 8)
            inside = (z > 0) & (-d[:, 1] > ca)
            want = np.bincount((sector + band)[inside], weights=z[inside], minlength=16) * 4.0 / len(d)
            assert np.abs(got - want).max() < 0.004  # measured 0.0027
