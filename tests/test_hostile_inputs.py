"""Hostile inputs and options (issue 19): meshes at extreme scales, files that are not
regular files, OFF files whose counts lie, USD meshes without triangles, NaN/inf and
huge values in options, and the memory bound of ray chunking."""

from __future__ import annotations

import logging
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import aobake
from aobake.cli import main
from aobake.errors import InputError
from aobake.io import load_mesh
from aobake.mesh import surface_from_arrays
from aobake.methods.embree.estimator import embree_ao, estimate, ray_chunks
from aobake.methods.embree.options import EmbreeOptions
from aobake.testing import scenes
from aobake.tracing import power_of_two_scale

REPO = Path(__file__).resolve().parents[1]
TRI_PLY = (
    "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
    "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
    "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
)


def _one_line_error(result, code=1):
    """The CLI failed with ``code`` and one ``Error:`` line, no traceback."""
    assert result.exit_code == code, result.output
    assert "Traceback" not in result.output
    errors = [line for line in result.output.splitlines() if line.startswith("Error")]
    assert len(errors) == 1, result.output
    return errors[0]


@pytest.fixture(scope="module")
def tri(tmp_path_factory):
    path = tmp_path_factory.mktemp("tri") / "tri.ply"
    path.write_text(TRI_PLY)
    return path


# -- scale ---------------------------------------------------------------------------


@pytest.mark.parametrize("scale", [1e-40, 1e-30, 1e-20, 1e-15, 1e15, 1e20, 1e30, 2e38])
def test_inside_of_sphere_closed_at_any_scale(scale):
    # Every ray from inside a closed sphere hits it: ao = 0 exactly (main read 1 here).
    s = scenes.sphere(1.0, 2, inward=True)
    t = surface_from_arrays(s.positions * scale, s.faces)
    np.testing.assert_array_equal(embree_ao(t, n_rays=16).ao, 0.0)


@pytest.mark.parametrize("exponent", [-130, -50, 40, 126])
def test_power_of_two_scaling_is_bit_identical(exponent):
    # The tracer divides by a power of two, so scaling a mesh by one changes no bit.
    s, _ = scenes.sphere_on_ground(0.5, 1, gap=0.0, cells=4)
    ref = embree_ao(s, n_rays=32, seed=2).ao
    k = math.ldexp(1.0, exponent)
    t = surface_from_arrays(s.positions * k, s.faces, s.normals)
    np.testing.assert_array_equal(embree_ao(t, n_rays=32, seed=2).ao, ref)


@pytest.mark.parametrize("scale", [1e-30, 1e30])
def test_disk_method_agrees_with_rays_at_extreme_scale(scale):
    s, _ = scenes.sphere_on_ground(0.5, 1, gap=0.0, cells=4)
    t = surface_from_arrays(s.positions * scale, s.faces)
    rays = np.asarray(aobake.bake(t, "embree", n_rays=256))
    disks = np.asarray(aobake.bake(t, "bunnell"))
    assert np.sqrt(np.mean((rays - disks) ** 2)) < 0.1
    assert rays.min() < 0.5  # the contact under the ball is dark, not open


def test_power_of_two_scale():
    assert power_of_two_scale(1.0) == 2.0 and power_of_two_scale(0.75) == 1.0
    for m in (1e-300, 3e-40, 0.5, 7.0, 2e38, 1e300):
        assert 0.5 <= m / power_of_two_scale(m) < 1.0
    assert power_of_two_scale(0.0) == 1.0 and power_of_two_scale(math.inf) == 1.0


def test_zero_and_huge_extent_refused():
    with pytest.raises(InputError, match="zero extent"):
        aobake.bake(surface_from_arrays(np.ones((3, 3)), [[0, 1, 2]]), "embree", n_rays=4)
    with pytest.raises(InputError, match="span 2e\\+300"):
        surface_from_arrays([[0, 0, 0], [1e300, 0, 0], [-1e300, 1, 0]], [[0, 1, 2]])
    with pytest.raises(InputError, match="less than"):
        surface_from_arrays([[0, 0, 0], [1e-70, 0, 0], [0, 1e-70, 0]], [[0, 1, 2]])


# -- files that are not regular files --------------------------------------------------


def test_fifo_refused_without_blocking(tmp_path):
    fifo = tmp_path / "mesh.ply"
    os.mkfifo(fifo)
    run = subprocess.run(
        [sys.executable, "-m", "aobake", "bake", str(fifo), "-o", str(tmp_path / "o.ply")],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    assert run.returncode == 1
    assert run.stderr.strip() == "Error: mesh.ply: is a FIFO, not a mesh file; give a regular file"
    assert not (tmp_path / "o.ply").exists()


@pytest.mark.parametrize(
    "args",
    [
        ["bake", "{x}", "-o", "{d}/o.ply"],
        ["compare", "{x}", "{x}"],
        ["preview", "{x}", "-o", "{d}/o.png"],
        ["bake", "{tri}", "-o", "{d}/o.ply", "--field", "{xz}"],
    ],
)
@pytest.mark.parametrize("kind", ["dev_zero", "directory"])
def test_inputs_that_are_not_regular_files(tmp_path, tri, args, kind):
    x = tmp_path / "x.ply"
    xz = tmp_path / "x.npz"
    if kind == "dev_zero":
        x.symlink_to("/dev/zero")
        xz.symlink_to("/dev/zero")
        expect = "is a character device"
    else:
        x.mkdir()
        xz.mkdir()
        expect = "is a directory"
    argv = [a.format(x=x, xz=xz, d=tmp_path, tri=tri) for a in args]
    line = _one_line_error(CliRunner().invoke(main, argv))
    assert expect in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.npz", "x.ply"]


# -- OFF counts ------------------------------------------------------------------------

OFF_ROWS = "0 0 0\n1 0 0\n0 1 0\n1.5 1 0\n3 0 1 2\n3 1 3 2\n"


@pytest.mark.parametrize(
    "text,problem",
    [
        ("OFF\n6 2 0\n" + OFF_ROWS, "promises 6 vertices"),  # face rows would become vertices
        ("OFF\n4 2 0\n" + OFF_ROWS[:-8], "truncated"),
        ("OFF\n4 1 0\n" + OFF_ROWS, "1 more rows follow"),
        ("OFF\n3 3 0\n" + OFF_ROWS, "OFF face 0 is not a polygon row"),  # a vertex as a face
        ("OFF\nx y z\n" + OFF_ROWS, "bad counts"),
    ],
)
def test_off_counts_that_lie_are_refused(tmp_path, text, problem):
    path = tmp_path / "m.off"
    path.write_text(text)
    with pytest.raises(InputError, match=problem):
        load_mesh(path)
    line = _one_line_error(CliRunner().invoke(main, ["bake", str(path), "-o", str(tmp_path / "o.ply")]))
    assert line.startswith("Error: m.off: ")


def test_honest_off_files_still_read(tmp_path):
    path = tmp_path / "m.off"
    path.write_text("# comment\nOFF 4 2 0\n0 0 0\n1 0 0 # c\n0 1 0\n1 1 0\n3 0 1 2 255 0 0\n4 0 1 3 2\n")
    s = load_mesh(path)
    assert s.n_vertices == 4 and s.n_faces == 3


# -- USD meshes without triangles --------------------------------------------------------


def _flat_usd(path):
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.CreateNew(str(path))
    floor = UsdGeom.Mesh.Define(stage, "/floor")
    floor.CreatePointsAttr([(-1, 0, -1), (1, 0, -1), (1, 0, 1), (-1, 0, 1)])
    floor.CreateFaceVertexCountsAttr([4])
    floor.CreateFaceVertexIndicesAttr([0, 3, 2, 1])
    lines = UsdGeom.Mesh.Define(stage, "/lines")
    lines.CreatePointsAttr([(0, 0.5, 0), (0.5, 0.5, 0), (0, 1, 0)])
    lines.CreateFaceVertexCountsAttr([2, 2])
    lines.CreateFaceVertexIndicesAttr([0, 1, 1, 2])
    holes = UsdGeom.Mesh.Define(stage, "/holes")
    holes.CreatePointsAttr([(0, 0.2, 0), (0.2, 0.2, 0), (0, 0.2, 0.2)])
    holes.CreateFaceVertexCountsAttr([3])
    holes.CreateFaceVertexIndicesAttr([0, 1, 2])
    holes.CreateHoleIndicesAttr([0])
    stage.Save()


def test_usd_meshes_without_triangles_keep_their_vertices(tmp_path, caplog):
    src = tmp_path / "flat.usda"
    _flat_usd(src)
    with caplog.at_level(logging.WARNING):
        s = load_mesh(src)
    assert s.n_vertices == 10 and [p.name for p in s.parts] == ["floor", "lines", "holes"]
    assert sum("no triangle" in r.getMessage() for r in caplog.records) == 1
    for out in ("o.ply", "o.usda"):
        result = CliRunner().invoke(main, ["bake", str(src), "-o", str(tmp_path / out), "--rays", "16", "-q"])
        assert result.exit_code == 0, result.output
        ao = aobake.io.read_bake(tmp_path / out)
        assert ao.shape == (10,) and np.isfinite(ao).all()


# -- options -------------------------------------------------------------------------------

FLOAT_OPTIONS = [
    ["bake", "{tri}", "-o", "{d}/o.ply", "--max-distance"],
    ["bake", "{tri}", "-o", "{d}/o.ply", "--bias"],
    ["bake", "{tri}", "-o", "{d}/o.ply", "--tolerance"],
    ["bake", "{tri}", "-o", "{d}/o.ply", "--method", "bunnell", "--theta"],
    ["bake", "{tri}", "-o", "{d}/o.ply", "--method", "bunnell", "--near"],
    ["bake", "{tri}", "-o", "{d}/o.ply", "--method", "bunnell", "--max-distance"],
    ["bake", "{tri}", "-o", "{d}/o.usda", "--meters-per-unit"],
    ["field", "{tri}", "-o", "{d}/o.npz", "--r-far"],
    ["compare", "{tri}", "{tri}", "--threshold"],
    ["preview", "{tri}", "-o", "{d}/o.png", "--azimuth"],
    ["preview", "{tri}", "-o", "{d}/o.png", "--elevation"],
]


@pytest.mark.parametrize("value", ["nan", "inf", "-inf"])
@pytest.mark.parametrize("args", FLOAT_OPTIONS, ids=lambda a: f"{a[0]}{a[-1]}")
def test_nan_and_inf_refused_in_float_options(tmp_path, tri, args, value):
    if value == "inf" and args[-1] in ("--theta", "--r-far"):
        pytest.skip("+inf is meaningful here: theta = never approximate; r-far names the limit")
    argv = [a.format(tri=tri, d=tmp_path) for a in args] + [value]
    line = _one_line_error(CliRunner().invoke(main, argv), code=2)
    assert args[-1] in line
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "args",
    [
        ["bake", "{tri}", "-o", "{d}/o.ply", "--rays", str(2**32 + 1)],
        ["bake", "{tri}", "-o", "{d}/o.ply", "--rays", str(2**40)],
        ["bake", "{tri}", "-o", "{d}/o.ply", "--rays", str(2**70)],
        ["field", "{tri}", "-o", "{d}/o.npz", "--rays", str(2**20 + 1)],
        ["field", "{tri}", "-o", "{d}/o.npz", "--resolution", str(2**40)],
        ["field", "{tri}", "-o", "{d}/o.npz", "--radial-samples", "100000"],
        ["field", "{tri}", "-o", "{d}/o.npz", "--raster-size", "100000"],
        ["field", "{tri}", "-o", "{d}/o.npz", "--prefilter", "1000"],
    ],
    ids=lambda a: " ".join(a[-2:]),
)
def test_huge_counts_refused(tmp_path, tri, args):
    argv = [a.format(tri=tri, d=tmp_path) for a in args]
    line = _one_line_error(CliRunner().invoke(main, argv), code=2)
    assert args[-2] in line and "range" in line


@pytest.mark.parametrize("method", ["embree", "bunnell"])
def test_threads_above_the_cores_are_clamped(tmp_path, tri, method):
    out = tmp_path / "o.ply"
    argv = ["bake", str(tri), "-o", str(out), "--method", method, "--threads", "1000"]
    result = CliRunner().invoke(main, argv)
    assert result.exit_code == 0, result.output
    assert f"--threads 1000: this machine has {os.cpu_count()} cores" in result.output
    ref = tmp_path / "ref.ply"
    CliRunner().invoke(main, ["bake", str(tri), "-o", str(ref), "--method", method, "--threads", "1"])
    np.testing.assert_array_equal(aobake.io.read_bake(out), aobake.io.read_bake(ref))


# -- memory: rays in bounded chunks --------------------------------------------------------


@pytest.mark.parametrize("n_active,j0,j1,chunk", [(3, 0, 10**8, 1 << 20), (5, 16, 1000, 64), (1000, 0, 256, 4096)])
def test_ray_chunks_bounded_and_complete(n_active, j0, j1, chunk):
    active = np.arange(n_active, dtype=np.int64) * 2
    seen = {}
    for vertices, a, b in ray_chunks(active, j0, j1, chunk, threads=2):
        assert 0 < vertices.size * (b - a) <= chunk
        for v in vertices.tolist():
            seen.setdefault(v, []).append((a, b))
    for v in active.tolist():  # each vertex's ranges tile [j0, j1) in order
        ranges = seen[v]
        assert ranges[0][0] == j0 and ranges[-1][1] == j1
        assert all(r[1] == s[0] for r, s in zip(ranges[:-1], ranges[1:], strict=True))


@pytest.mark.parametrize("threads", [1, 3])
def test_chunked_rays_are_bit_identical(threads):
    # A vertex's rays split over chunks (and threads) count the same hits.
    s, _ = scenes.sphere_on_ground(0.5, 1, gap=0.0, cells=4)
    for opts in (EmbreeOptions(n_rays=300, seed=1), EmbreeOptions(n_rays=256, tolerance=0.05)):
        ref = estimate(s, opts).ao
        for chunk in (7, 64, 1000):
            alt = EmbreeOptions(**{**opts.__dict__, "threads": threads})
            np.testing.assert_array_equal(estimate(s, alt, chunk_rays=chunk).ao, ref)


# -- contacts in float32 inputs ------------------------------------------------------------


@pytest.mark.parametrize("shift", [(0.3, 0.7, 0.1), (0.0, 0.0, 0.0), (12.3, -4.1, 0.9)])
def test_float32_corner_on_a_floor_vertex_reads_closed(shift):
    # A unit box whose bottom corners sit exactly on vertices of a floor grid, with
    # coordinates rounded to float32 as a GLB stores them. The contact probe passes
    # through the floor exactly at a vertex, where Embree's non-robust traversal leaked
    # (main read two corners 0.81 and 0.77 open at the first shift); the probe scene is
    # now robust, and the corners read as in float64: the floor fills ~3/4 of the
    # hemisphere about their diagonal normals.
    import trimesh

    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    bv = box.vertices + [0, 0, 0.5]
    gp, gf = scenes.ground_grid(2.0, 16)
    positions = np.vstack([bv, gp]) + shift
    faces = np.vstack([box.faces, gf + 8])
    bottom = np.flatnonzero(bv[:, 2] < 1e-9)
    ao = {}
    for dtype in (np.float64, np.float32):
        s = surface_from_arrays(positions.astype(dtype).astype(np.float64), faces)
        ao[dtype] = embree_ao(s, n_rays=64).ao[bottom]
    assert ao[np.float32].max() < 0.3
    assert np.abs(ao[np.float32] - ao[np.float64]).max() <= 2 / 64


# -- memory: previews in bands of rows ------------------------------------------------------


@pytest.mark.parametrize("size,band", [(97, 256), (97, 1), (130, 7), (64, 64)])
def test_preview_bands_give_the_same_file(size, band):
    # Rendering a band of rows at a time (bounded memory at --size 8192) writes the very
    # bytes of the whole-image render.
    from aobake.tools.preview import grey, png_bytes, preview_png, render_values

    s, _ = scenes.sphere_on_ground(0.5, 2, gap=0.0, cells=6)
    values = np.linspace(0.0, 1.0, s.n_vertices)
    whole = png_bytes(grey(render_values(s.positions, s.faces, values, size=size, up="Z", view="iso")))
    banded = preview_png(s.positions, s.faces, values, size=size, band_rows=band, up="Z", view="iso")
    assert banded == whole


# -- the disk method on needles --------------------------------------------------------------

NEEDLES = (
    # a needle and an almost collinear sliver (edges 1e-9 of the scene): in the disk
    # method's float32 terms the receiver's own disk, lifted 1e-4 disk radii above it,
    # gave r^2 (pi r^2 + A) = 0 and 0 / 0 = NaN (found by fuzzing needles at 1e30)
    [
        [0.18727186130468504, -0.27374465076469623, 0.23181086176796964],
        [0.46368160251798635, -0.31610307696995754, 0.19020606393998638],
        [0.3201183961274917, -0.2941027254013409, 0.21181499187138172],
        [0.5109625645468612, 0.4252309099879812, 0.10855601724430916],
        [1.3002006222224844, -1.3568628461535328, 0.06167850530018773],
        [2.089438679898108, -3.138956602295048, 0.01480099335606627],
    ],
    [[0, 1, 2], [3, 4, 5]],
)


@pytest.mark.parametrize("scale", [1.0, 1e30])
@pytest.mark.parametrize("options", [{}, {"passes": 2}, {"near": 0.0}])
def test_disk_method_finite_on_needles(scale, options):
    positions, faces = NEEDLES
    s = surface_from_arrays(np.array(positions) * scale, faces)
    ao = np.asarray(aobake.bake(s, "bunnell", **options))
    # the two slivers lie far apart and nearly edge-on to each other: every vertex is open
    np.testing.assert_array_equal(ao, 1.0)
