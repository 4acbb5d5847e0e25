"""Fitting AO fields (aobake.methods.fields.fit): closed forms on a sphere, a box against
Embree, degenerate occluders, options, compiled kernels, and the `aobake field` command."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from aobake.errors import InputError
from aobake.mesh import surface_from_arrays
from aobake.methods.embree import embree_ao
from aobake.methods.fields import (
    FieldOptions,
    cap_integral,
    field_ao,
    fit_field,
    load_field,
    rigid_transform,
)
from aobake.testing import scenes
from aobake.testing.field_scenes import ball_fields as fit_ball_fields
from aobake.testing.field_scenes import plane_receivers

# --------------------------------------------------------------------------- fits


@pytest.fixture(scope="module")
def ball():
    return scenes.sphere(1.0, 3)


@pytest.fixture(scope="module")
def ball_fields():
    return fit_ball_fields()


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
    c = fit_field(box, sampler="embree", resolution=3, radial_samples=5, n_rays=64, threads=1)
    d = fit_field(box, sampler="embree", resolution=3, radial_samples=5, n_rays=64, threads=2)
    np.testing.assert_array_equal(c.texels, d.texels)


def test_fit_does_not_depend_on_chunks(box_setup, monkeypatch):
    """The texel fit runs per chunk of texels on worker threads: one texel per call and
    all texels in one call give the same bits (each texel is fitted on its own)."""
    from aobake.methods.fields import fit as fit_module

    box, _ = box_setup
    got = []
    for task in (1, 10**6):
        monkeypatch.setattr(fit_module, "_FIT_TASK", task)
        got.append(fit_field(box, resolution=3, radial_samples=5, raster_size=16))
    np.testing.assert_array_equal(got[0].texels, got[1].texels)
    np.testing.assert_array_equal(got[0].residuals, got[1].residuals)


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
    with pytest.raises(TypeError, match="FieldOptions has no option 'rays'"):
        fit_field(ball, rays=16)


def test_options_instance_and_keywords_agree(box_setup):
    box, _ = box_setup
    kw = dict(resolution=3, radial_samples=5, raster_size=16)
    a = fit_field(box, FieldOptions(**kw))
    b = fit_field(box, FieldOptions(resolution=5), **{**kw, "resolution": 3})
    np.testing.assert_array_equal(a.texels, b.texels)


def test_translated_occluder_gives_the_same_field(box_setup):
    box, _ = box_setup
    shift = np.array([1e4, -2e3, 37.0])
    a = fit_field(box, resolution=3, radial_samples=5, raster_size=16)
    b = fit_field(surface_from_arrays(box.positions + shift, box.faces), resolution=3, radial_samples=5, raster_size=16)
    np.testing.assert_allclose(b.centre - a.centre, shift, rtol=1e-12)
    np.testing.assert_allclose(b.texels, a.texels, rtol=1e-4, atol=1e-5)


# --------------------------------------------------------------------------- kernels


def test_each_kernel_compiled_once(ball):
    """Coercion in the wrappers gives one specialization per kernel (no dtype drift)."""
    import numba

    from aobake.kernels import cap, field_eval, field_fit, footprint, hull, raster

    if numba.config.DISABLE_JIT:
        pytest.skip("JIT disabled")
    for model in ("paper", "table"):
        for sampler in ("raster", "embree"):
            f = fit_field(ball, sampler=sampler, model=model, resolution=2, radial_samples=3, raster_size=8, n_rays=16)
            field_ao(f, np.ones((3, 3)), np.zeros((3, 3)), transform=np.eye(4))
    cap_integral([1.0, 2.0], 0.5)
    for kernel in (
        cap.cap_occlusion_array,
        hull.support_values,
        hull.hull_distances,
        footprint.footprint_rays,
        footprint.accumulate_hits,
        field_fit.fit_texels,
        field_eval.evaluate,
        raster.render_points,
    ):
        assert len(kernel.signatures) == 1, (kernel, kernel.signatures)


def _specialisations(kernel):
    """Signatures compiled in this process and those in the kernel's numba cache index
    (a cached caller loads its callees inside it, so a warm run compiles none)."""
    found = {str(sig) for sig in kernel.signatures}
    cache = getattr(kernel, "_cache", None)
    if cache is not None and hasattr(cache, "_cache_file"):
        found |= {str(key[0]) for key in cache._cache_file._load_index()}
    return found


def test_field_helpers_have_one_specialisation(ball):
    """The helpers the texel fit and the rasterizer call are typed once: no literal
    counter (``m = 0``) and no mix of C and strided arrays adds a second compile (issue
    19). ``_solve_small`` keeps its literal-3 version: compiled for a constant size, its
    loops give other last bits, and results must not change."""
    import numba

    from aobake.kernels import field_fit, raster

    if numba.config.DISABLE_JIT:
        pytest.skip("JIT disabled")
    fit_field(ball, resolution=2, radial_samples=3, raster_size=8)
    for kernel in (
        field_fit._den_min,
        field_fit._centre_cost,
        field_fit._fit_denominator,
        field_fit._refine_omega,
        field_fit._refine_centre,
        field_fit._fit_centre,
        raster._fill_polygon,
        raster._clip_to_face,
        raster._render_point,
    ):
        sigs = _specialisations(kernel)
        assert len(sigs) == 1, (kernel.py_func.__name__, sigs)


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


def test_field_command_is_built_from_field_options():
    from aobake.options import flag, specs

    text = _run(["field", "--help"]).output
    for name, (spec, default) in specs(FieldOptions).items():
        assert flag(name, spec) in text, name
        shown = f"[default: {spec.none}]" if default is None else f"[default: {default}"
        assert shown in " ".join(text.split()), (name, shown)


def test_field_spec_parsing():
    from aobake.cli import FieldSpec

    spec = FieldSpec()
    assert spec.convert("rock.npz", None, None) == (Path("rock.npz"), None)
    assert spec.convert("a@b/rock.npz", None, None) == (Path("a@b/rock.npz"), None)
    assert spec.convert("rock.npz@1,-2,3e-1", None, None) == (Path("rock.npz"), (1.0, -2.0, 0.3))
    assert spec.convert("r.npz@0,0,0,90,0,-45", None, None) == (Path("r.npz"), (0.0, 0.0, 0.0, 90.0, 0.0, -45.0))
