"""Ambient occlusion fields: cap integral, hull distances, fits, evaluation, files."""

from __future__ import annotations

import math
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aobake.errors import InputError
from aobake.field import (
    AOField,
    cap_integral,
    field_ao,
    fields_ao,
    fit_field,
    hull_distance,
    load_field,
    rigid_transform,
    save_field,
    surface_centre,
)
from aobake.mesh import surface_from_arrays
from aobake.methods.embree import embree_ao
from aobake.testing import scenes

# --------------------------------------------------------------------------- cap integral


def cap_numeric(omega: float, ct: float, n: int = 800) -> float:
    """1/pi int_cap max(0, n.w) dw by midpoint quadrature in the cap's own frame."""
    cs = 1.0 - omega / (2.0 * math.pi)
    st_ = math.sqrt(max(0.0, 1.0 - ct * ct))
    # polar angle t about the cap axis a = (st, 0, ct), azimuth p
    sigma = math.acos(max(-1.0, min(1.0, cs)))
    t = (np.arange(n) + 0.5) / n * sigma
    p = (np.arange(2 * n) + 0.5) / (2 * n) * 2.0 * math.pi
    tt, pp = np.meshgrid(t, p, indexing="ij")
    # w = cos t a + sin t (cos p e1 + sin p e2) with e1 = (ct, 0, -st), e2 = (0, 1, 0)
    wz = np.cos(tt) * ct - np.sin(tt) * np.cos(pp) * st_
    d_area = np.sin(tt) * (sigma / n) * (math.pi / n)
    return float((np.maximum(wz, 0.0) * d_area).sum() / math.pi)


def test_cap_reference_values():
    np.testing.assert_allclose(cap_integral(math.pi, [1.0, 0.0, -1.0]), [0.75, 0.1955011, 0.0], atol=1e-6)
    np.testing.assert_allclose(cap_integral(2.0 * math.pi, [1.0, 0.0, -1.0]), [1.0, 0.5, 0.0], atol=1e-12)
    np.testing.assert_allclose(cap_integral(4.0 * math.pi, [1.0, 0.3, -1.0]), 1.0, atol=1e-12)
    np.testing.assert_allclose(cap_integral(0.0, [1.0, 0.0, -1.0]), 0.0, atol=0)


@pytest.mark.parametrize("omega", [0.05, 1.0, math.pi, 5.0, 2.0 * math.pi - 1e-3, 8.0, 12.0])
@pytest.mark.parametrize("ct", [1.0, 0.9, 0.3, 0.0, -0.4, -0.95, -1.0])
def test_cap_matches_numerical_integration(omega, ct):
    np.testing.assert_allclose(cap_integral(omega, ct), cap_numeric(omega, ct), atol=2e-4)


@settings(max_examples=200)
@given(st.floats(0.0, 4.0 * math.pi), st.floats(-1.0, 1.0))
def test_cap_complement_and_range(omega, ct):
    a = float(cap_integral(omega, ct))
    assert 0.0 <= a <= 1.0
    # the rest of the sphere is the opposite cap: C(4pi - Omega, -ct) = 1 - C(Omega, ct)
    np.testing.assert_allclose(cap_integral(4.0 * math.pi - omega, -ct), 1.0 - a, atol=1e-9)


def test_cap_is_finite_at_the_guards():
    om = np.array([2.0 * math.pi, 2.0 * math.pi, np.nextafter(2.0 * math.pi, 0), np.nan, -1.0, 1e-300, 20.0])
    ct = np.array([1.0, -1.0, 1.0, 0.5, 0.5, 0.0, np.nan])
    out = cap_integral(om, ct)
    assert np.isfinite(out[:6]).all()
    np.testing.assert_allclose(out[:3], [1.0, 0.0, 1.0], atol=1e-6)


# --------------------------------------------------------------------------- convex hull


def exact_convex_distance(s, centre, dirs):
    """Ray exit distance through a convex mesh, face by face."""
    p = s.positions - centre
    f = s.faces
    n = np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    off = np.einsum("ij,ij->i", n, p[f[:, 0]])
    n, off = n * np.sign(off)[:, None], np.abs(off)
    dn = dirs @ n.T
    return np.where(dn > 1e-12, off / np.where(dn > 1e-12, dn, 1.0), np.inf).min(axis=1)


@pytest.mark.parametrize(
    "surface",
    [scenes.box((1.0, 2.0, 3.0)), scenes.sphere(1.0, 2), scenes.random_convex(4, 2, scale=100.0)],
    ids=["box", "icosphere", "affine"],
)
def test_hull_distance_is_exact_on_convex_polyhedra(surface):
    centre = surface_centre(surface.positions, surface.faces)
    dirs = np.random.default_rng(5).normal(size=(300, 3))
    dirs = np.vstack([dirs, np.eye(3), -np.eye(3), [[1, 1, 1]]])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    got = hull_distance(surface.positions, dirs, centre)
    np.testing.assert_allclose(got, exact_convex_distance(surface, centre, dirs), rtol=1e-10)


def test_hull_distance_of_a_nonconvex_mesh_is_its_hulls():
    # a box with a dent on top (a vertex pushed in): the hull is the box
    box = scenes.box((2.0, 2.0, 2.0))
    dented = np.vstack([box.positions, [[0.0, 0.0, 0.2]]])
    top = np.flatnonzero(np.isclose(box.positions[:, 2], 1.0))
    extra = np.array([[top[0], top[1], 8], [top[1], top[2], 8]])
    s = surface_from_arrays(dented, np.vstack([box.faces, extra]))
    dirs = np.array([[0.0, 0.0, 1.0], [0.1, 0.0, 1.0]])
    got = hull_distance(s.positions, dirs, np.zeros(3))
    np.testing.assert_allclose(got, [1.0, math.hypot(0.1, 1.0)], rtol=1e-12)


# --------------------------------------------------------------------------- fits


@pytest.fixture(scope="module")
def ball():
    return scenes.sphere(1.0, 3)


@pytest.fixture(scope="module")
def ball_fields(ball):
    kw = dict(resolution=6, radial_samples=10)
    return {
        "raster": fit_field(ball, sampler="raster", raster_size=48, **kw),
        "embree": fit_field(ball, sampler="embree", rays=1024, **kw),
        "paper": fit_field(ball, sampler="raster", raster_size=48, model="paper", **kw),
        "table": fit_field(ball, sampler="raster", raster_size=48, model="table", **kw),
    }


def plane_receivers(height: float, half: float = 2.5, n: int = 9, z_axis: int = 2):
    t = np.linspace(-half, half, n)
    x, y = np.meshgrid(t, t, indexing="ij")
    p = np.zeros((x.size, 3))
    p[:, (z_axis + 1) % 3] = x.ravel()
    p[:, (z_axis + 2) % 3] = y.ravel()
    p[:, z_axis] = -height
    normals = np.zeros_like(p)
    normals[:, z_axis] = 1.0
    return p, normals


def sphere_ao(points, normals, radius=1.0):
    """Exact 1 - A under a sphere at the origin: a sphere seen from a point is a cap."""
    r = np.linalg.norm(points, axis=1)
    om = 2.0 * math.pi * (1.0 - np.sqrt(1.0 - (radius / r) ** 2))
    ct = np.einsum("ij,ij->i", -points / r[:, None], normals)
    return 1.0 - cap_integral(om, ct)


@pytest.mark.parametrize("kind", ["raster", "embree", "paper", "table"])
@pytest.mark.parametrize("height", [1.02, 1.3, 2.0, 4.0])
def test_sphere_field_matches_exact(ball_fields, kind, height):
    f = ball_fields[kind]
    p, n = plane_receivers(height)
    got = field_ao(f, p, n)
    want = sphere_ao(p, n)
    # the model error plus the icosphere's flattening (inradius 0.98)
    assert np.abs(got - want).max() < 0.03, (kind, np.abs(got - want).max())


def test_sphere_field_directions_point_to_the_centre(ball_fields):
    f = ball_fields["raster"]
    # all Y are parallel to the texel's ray: C_o stays finite, Y~ = -w at every r
    c = f.texels[..., 4:7].astype(np.float64)
    assert np.isfinite(c).all() and np.abs(c).max() < 2.0 * f.r_far
    assert f.y_rms_degrees < 1.0


@pytest.fixture(scope="module")
def box_setup():
    box = scenes.box((1.0, 1.6, 0.8))
    f = fit_field(box, sampler="raster", resolution=16, radial_samples=12, raster_size=48)
    return box, f


# RMSE and largest error measured at resolution 16 (0.035/0.16, 0.039/0.17, 0.023/0.08,
# 0.006/0.02), with margin: the error sits along the edges of the bottom face, where
# Omega and Y change within a texel
@pytest.mark.parametrize(
    "gap, rmse, worst", [(0.0, 0.045, 0.25), (0.1, 0.05, 0.25), (0.5, 0.03, 0.12), (1.5, 0.01, 0.04)]
)
def test_box_field_against_embree(box_setup, gap, rmse, worst):
    box, f = box_setup
    gp, gf = scenes.ground_grid(2.0, 16, z=-0.4 - gap)
    scene = surface_from_arrays(np.vstack([gp, box.positions]), np.vstack([gf, box.faces + len(gp)]))
    ref = embree_ao(scene, n_rays=1024).ao[: len(gp)]
    got = field_ao(f, gp, scene.normals[: len(gp)])
    err = got - ref
    assert np.sqrt(np.mean(err**2)) < rmse, np.sqrt(np.mean(err**2))
    assert np.abs(err).max() < worst


def test_fit_does_not_depend_on_threads(box_setup):
    box, _ = box_setup
    a = fit_field(box, resolution=3, radial_samples=5, raster_size=16, threads=1)
    b = fit_field(box, resolution=3, radial_samples=5, raster_size=16, threads=2)
    np.testing.assert_array_equal(a.texels, b.texels)
    c = fit_field(box, sampler="embree", resolution=3, radial_samples=5, rays=64, threads=1)
    d = fit_field(box, sampler="embree", resolution=3, radial_samples=5, rays=64, threads=2)
    np.testing.assert_array_equal(c.texels, d.texels)


def test_flat_plate_has_empty_directions_and_no_nan():
    gp, gf = scenes.ground_grid(1.0, 2)
    plate = surface_from_arrays(gp, gf)
    # odd resolution: a row of texel centres lies in the plate's plane, edge-on
    f = fit_field(plate, resolution=3, radial_samples=6, raster_size=16)
    g = fit_field(plate, resolution=4, radial_samples=6, raster_size=16, prefilter=2, model="table")
    empty = ~f.texels[..., :3].any(axis=-1)
    assert empty.sum() == 4 * 5  # the middle row of each side face, border included
    rng = np.random.default_rng(0)
    p = rng.normal(size=(500, 3))
    p[:50, 2] = 0.0  # in the plane
    n = rng.normal(size=(500, 3))
    for field in (f, g):
        assert np.isfinite(field.texels).all() and np.isfinite(field.residuals).all()
        ao = field_ao(field, p, n)
        assert np.isfinite(ao).all() and (ao >= 0).all() and (ao <= 1).all()


def test_bad_options_fail_fast(ball):
    with pytest.raises(ValueError, match="sampler"):
        fit_field(ball, sampler="gpu")
    with pytest.raises(ValueError, match="radial_samples"):
        fit_field(ball, radial_samples=2)
    with pytest.raises(InputError, match="r_far 0.5 must exceed"):
        fit_field(ball, r_far=0.5)
    with pytest.raises(ValueError, match="model"):
        fit_field(ball, model="spline")


# --------------------------------------------------------------------------- evaluation


def test_receivers_at_centre_hull_inside_and_far(ball_fields):
    f = ball_fields["raster"]
    c = f.centre
    r0 = float(f.texels[..., 3].mean())
    p = np.array(
        [c, c + [0, 0, r0], c + [0.3, 0.2, 0.1], c + [0, 0, f.r_far], c + [f.r_far * 2, 0, 0], c + [0, 0, f.r_near]]
    )
    for normals in (np.tile([0.0, 0.0, 1.0], (len(p), 1)), np.zeros((len(p), 3))):
        res = fields_ao([f], p, normals)
        assert np.isfinite(res.ao).all() and (res.ao >= 0).all() and (res.ao <= 1).all()
        assert res.skipped == (2,)
        np.testing.assert_array_equal(res.ao[3:5], 1.0)
        assert res.ao[0] == pytest.approx(1.0 - f.a0)  # the centre reads A0


def test_transform_invariance(ball_fields):
    f = ball_fields["table"]
    p, n = plane_receivers(1.2, n=7)
    p += [0.0123, 0.0456, 0.0]  # off the cube map's face seams, where rounding may pick either face
    base = field_ao(f, p, n)
    m = rigid_transform((3.0, -20.0, 7.5), (30.0, -45.0, 110.0))
    moved = field_ao(f, p @ m[:3, :3].T + m[:3, 3], n @ m[:3, :3].T, transform=m)
    np.testing.assert_allclose(moved, base, atol=1e-9)


def test_translated_occluder_gives_the_same_field(box_setup):
    box, _ = box_setup
    shift = np.array([1e4, -2e3, 37.0])
    a = fit_field(box, resolution=3, radial_samples=5, raster_size=16)
    b = fit_field(surface_from_arrays(box.positions + shift, box.faces), resolution=3, radial_samples=5, raster_size=16)
    np.testing.assert_allclose(b.centre - a.centre, shift, rtol=1e-12)
    np.testing.assert_allclose(b.texels, a.texels, rtol=1e-4, atol=1e-5)


def test_rigid_transform_conventions():
    m = rigid_transform((1.0, 2.0, 3.0), (90.0, 0.0, 0.0))
    np.testing.assert_allclose(m[:3, :3] @ [0, 1, 0], [0, 0, 1], atol=1e-15)
    m = rigid_transform(rotation_degrees=(90.0, 90.0, 0.0))  # x first, then y
    np.testing.assert_allclose(m[:3, :3] @ [0, 1, 0], [1, 0, 0], atol=1e-15)
    with pytest.raises(ValueError, match="rigid"):
        field_ao_dummy = np.diag([2.0, 1.0, 1.0, 1.0])
        fields_ao([_tiny_field()], np.zeros((1, 3)), np.zeros((1, 3)), transforms=[field_ao_dummy])


def _tiny_field() -> AOField:
    return fit_field(scenes.box((1.0, 1.0, 1.0)), resolution=1, radial_samples=3, raster_size=8)


def test_several_fields_multiply(ball_fields):
    f1, f2 = ball_fields["raster"], ball_fields["embree"]
    p, n = plane_receivers(1.5, half=6.0)
    t1, t2 = rigid_transform((-1.2, 0, 0)), rigid_transform((1.2, 0, 0), (0, 0, 40))
    both = fields_ao([f1, f2], p, n, transforms=[t1, t2])
    a1 = field_ao(f1, p, n, transform=t1)
    a2 = field_ao(f2, p, n, transform=t2)
    np.testing.assert_array_equal(both.ao, a1 * a2)
    far = [int((np.linalg.norm(p - t[:3, 3] - f.centre, axis=1) >= f.r_far).sum()) for f, t in ((f1, t1), (f2, t2))]
    assert both.skipped == tuple(far) and sum(far) > 0


# --------------------------------------------------------------------------- files


def test_round_trip_and_reproducible_bytes(ball_fields, tmp_path):
    for kind in ("raster", "table"):
        f = ball_fields[kind]
        a, b = tmp_path / f"{kind}_a.npz", tmp_path / f"{kind}_b.npz"
        save_field(f, a)
        save_field(f, b)
        assert a.read_bytes() == b.read_bytes()
        g = load_field(a)
        np.testing.assert_array_equal(g.texels, f.texels)
        if f.table is not None:
            np.testing.assert_array_equal(g.table, f.table)
        assert g.model == f.model and g.params == f.params and g.occluder_hash == f.occluder_hash
        p, n = plane_receivers(1.1)
        np.testing.assert_array_equal(field_ao(g, p, n), field_ao(f, p, n))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["raster_a.npz", "raster_b.npz", "table_a.npz", "table_b.npz"]


def _rewrite(src, dst, **changes):
    with np.load(src) as z:
        data = {k: z[k] for k in z.files}
    for k, v in changes.items():
        if v is None:
            data.pop(k)
        else:
            data[k] = v
    np.savez(dst, **data)


def _expect_error(path, text):
    with pytest.raises(InputError) as info:
        load_field(path)
    msg = str(info.value)
    assert msg.startswith(f"{path.name}: ") and "\n" not in msg and text in msg, msg


def test_bad_files_fail_with_one_line(ball_fields, tmp_path):
    good = tmp_path / "good.npz"
    save_field(ball_fields["raster"], good)
    data = good.read_bytes()

    (tmp_path / "text.npz").write_text("not a zip\n")
    _expect_error(tmp_path / "text.npz", "not a readable field file")
    (tmp_path / "cut.npz").write_bytes(data[: len(data) // 2])
    _expect_error(tmp_path / "cut.npz", "not a readable field file")
    (tmp_path / "empty.npz").write_bytes(b"")
    _expect_error(tmp_path / "empty.npz", "not a readable field file")
    _expect_error(tmp_path / "missing_file.npz", "no such file")

    cases = {
        "nokey": ({"texels": None}, "missing texels"),
        "version": ({"format_version": np.array(99)}, "version 99"),
        "shape": ({"texels": np.zeros((6, 3, 3, 7), np.float32)}, "texels have shape"),
        "nan": ({"centre": np.array([0.0, np.nan, 0.0])}, "NaN"),
        "dtype": ({"texels": np.zeros((6, 8, 8, 7), np.int32)}, "floating point"),
        "radii": ({"r_far": np.array(0.5)}, "inconsistent radii"),
        "params": ({"params": np.array("[1, 2")}, "JSON"),
        "model": ({"model": np.array("spline")}, "model"),
    }
    for name, (change, text) in cases.items():
        path = tmp_path / f"{name}.npz"
        _rewrite(good, path, **change)
        _expect_error(path, text)

    # a corrupted member inside an intact zip directory
    bad = tmp_path / "crc.npz"
    with zipfile.ZipFile(good) as zin, zipfile.ZipFile(bad, "w") as zout:
        for item in zin.infolist():
            payload = zin.read(item)
            if item.filename == "texels.npy":
                payload = payload[:-40]
            zout.writestr(item, payload)
    _expect_error(bad, "not a readable field file")


# --------------------------------------------------------------------------- kernels


def test_each_kernel_compiled_once(ball):
    """Coercion in the wrappers gives one specialization per kernel (no dtype drift)."""
    import numba

    from aobake.kernels import field as KF
    from aobake.kernels import raster as KR

    if numba.config.DISABLE_JIT:
        pytest.skip("JIT disabled")
    for model in ("paper", "table"):
        for sampler in ("raster", "embree"):
            f = fit_field(ball, sampler=sampler, model=model, resolution=2, radial_samples=3, raster_size=8, rays=16)
            field_ao(f, np.ones((3, 3)), np.zeros((3, 3)), transform=np.eye(4))
    cap_integral([1.0, 2.0], 0.5)
    for kernel in (
        KF.cap_occlusion_array,
        KF.support_values,
        KF.hull_distances,
        KF.footprint_rays,
        KF.accumulate_hits,
        KF.fit_texels,
        KF.evaluate,
        KR.render_points,
    ):
        assert len(kernel.signatures) == 1, (kernel, kernel.signatures)


# --------------------------------------------------------------------------- command line


@pytest.fixture(scope="module")
def cli_files(tmp_path_factory):
    import trimesh

    d = tmp_path_factory.mktemp("cli")
    box = scenes.box((1.0, 1.0, 1.0))
    trimesh.Trimesh(box.positions, box.faces, process=False).export(d / "box.ply")
    gp, gf = scenes.ground_grid(2.0, 8, z=-0.5)
    trimesh.Trimesh(gp, gf, process=False).export(d / "ground.ply")
    return d


def _run(args):
    from click.testing import CliRunner

    from aobake.cli import main

    return CliRunner().invoke(main, [str(a) for a in args])


def test_cli_field_then_bake_multiplies(cli_files):
    from aobake.io import load_mesh, read_bake

    d = cli_files
    options = ["--resolution", "4", "--radial-samples", "5", "--raster-size", "16"]
    fit = _run(["field", d / "box.ply", "-o", d / "box.npz", *options])
    assert fit.exit_code == 0, fit.output
    assert fit.stderr.count("\n") == 1 and "residuals Omega" in fit.stderr and "box.npz" in fit.stderr
    f = load_field(d / "box.npz")
    assert f.resolution == 4 and f.params["raster_size"] == 16

    plain = _run(["bake", d / "ground.ply", "-o", d / "plain.ply", "--rays", "16", "-q"])
    assert plain.exit_code == 0 and plain.stderr == ""
    args = ["bake", d / "ground.ply", "-o", d / "with.ply", "--rays", "16"]
    args += ["--field", d / "box.npz", "--field", f"{d / 'box.npz'}@1.5,0,0.25,0,0,45"]
    both = _run(args)
    assert both.exit_code == 0, both.output
    assert "x 2 field(s)" in both.stderr and both.stderr.count("\n") == 1

    ground = load_mesh(d / "ground.ply")
    expect = read_bake(d / "plain.ply").astype(np.float64)
    expect *= field_ao(f, ground.positions, ground.normals)
    expect *= field_ao(f, ground.positions, ground.normals, transform=rigid_transform((1.5, 0, 0.25), (0, 0, 45)))
    np.testing.assert_allclose(read_bake(d / "with.ply"), expect, atol=1e-6)
    assert (read_bake(d / "with.ply") < read_bake(d / "plain.ply") - 0.1).any()


def test_cli_field_errors(cli_files, tmp_path):
    d = cli_files
    (tmp_path / "bad.npz").write_bytes(b"PK\x03\x04 truncated")
    out = tmp_path / "out.ply"
    r = _run(["bake", d / "ground.ply", "-o", out, "--rays", "4", "--field", tmp_path / "bad.npz"])
    assert r.exit_code == 1 and r.stderr.startswith("Error: bad.npz: not a readable field file")
    assert r.stderr.count("\n") == 1 and not out.exists()

    r = _run(["bake", d / "ground.ply", "-o", out, "--field", f"{tmp_path / 'bad.npz'}@1,2"])
    assert r.exit_code == 2 and "3 numbers" in r.stderr

    r = _run(["field", d / "box.ply", "-o", tmp_path / "box.txt"])
    assert r.exit_code == 1 and "box.txt: a field is written as .npz" in r.stderr
    r = _run(["field", d / "box.ply", "-o", tmp_path / "f.npz", "--r-far", "0.1"])
    assert r.exit_code == 1 and r.stderr.startswith("Error: box.ply: r_far 0.1 must exceed")
    assert not (tmp_path / "f.npz").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.npz"]


def test_field_spec_parsing():
    from aobake.cli import FieldSpec

    spec = FieldSpec()
    assert spec.convert("rock.npz", None, None) == (Path("rock.npz"), None)
    assert spec.convert("a@b/rock.npz", None, None) == (Path("a@b/rock.npz"), None)
    assert spec.convert("rock.npz@1,-2,3e-1", None, None) == (Path("rock.npz"), (1.0, -2.0, 0.3))
    assert spec.convert("r.npz@0,0,0,90,0,-45", None, None) == (Path("r.npz"), (0.0, 0.0, 0.0, 90.0, 0.0, -45.0))
