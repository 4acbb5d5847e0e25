"""sweep on lit scenes: irradiance rows scored against an independent reference, their
own Pareto front, the unlit outputs unchanged."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

from aobake.cli import main
from aobake.testing import scenes
from aobake.tools.sweep import SweepRow, light_grid, to_csv, to_json, to_markdown


def _grid_mesh(name, axis):
    """A 1 x 1 grid of 3 x 3 quads: the floor (y = 0, facing +y) or the back wall (z = 0,
    facing +z), as USD text."""
    t = np.linspace(0.0, 1.0, 4)
    u, v = np.meshgrid(t, t, indexing="ij")
    if axis == "y":
        points = np.c_[u.ravel(), np.zeros(u.size), v.ravel()]
    else:
        points = np.c_[u.ravel(), v.ravel(), np.zeros(u.size)]
    quads = []
    for i in range(3):
        for j in range(3):
            a = 4 * i + j
            quads.append([a, a + 1, a + 5, a + 4] if axis == "y" else [a, a + 4, a + 5, a + 1])
    pts = ", ".join(f"({x:g}, {y:g}, {z:g})" for x, y, z in points)
    idx = ", ".join(str(k) for q in quads for k in q)
    return (
        f'    def Mesh "{name}"\n    {{\n        int[] faceVertexCounts = [{", ".join(["4"] * 9)}]\n'
        f"        int[] faceVertexIndices = [{idx}]\n        point3f[] points = [{pts}]\n    }}\n"
    )


LIT_USDA = (
    '#usda 1.0\n(\n    defaultPrim = "World"\n    metersPerUnit = 1\n    upAxis = "Y"\n)\n\n'
    'def Xform "World"\n{\n'
    + _grid_mesh("floor", "y")
    + _grid_mesh("back", "z")
    + """    def RectLight "light"
    {
        float inputs:height = 0.3
        float inputs:intensity = 10
        float inputs:width = 0.3
        float3 xformOp:rotateXYZ = (-90, 0, 0)
        double3 xformOp:translate = (0.5, 0.8, 0.5)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
    }
}
"""
)


AO_GRID = [
    ("embree", "rays=4", {"n_rays": 4}),
    ("bunnell", "passes=1 theta=2", {"passes": 1, "theta": 2.0}),
]


@pytest.fixture(scope="module")
def lit_sweep(tmp_path_factory):
    """One sweep of the lit corner (both methods, 16 reference samples, no fields; two AO
    rows, the AO grid is test_sweep's)."""
    import aobake.tools.sweep as sweep_mod
    from aobake.pipeline import sweep_file

    d = tmp_path_factory.mktemp("lit")
    src = d / "corner.usda"
    src.write_text(LIT_USDA)
    out = d / "sw"
    plots = []  # drawing is test_irradiance_plot_names_its_front's; here: what is plotted where
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(sweep_mod, "default_grid", lambda methods: AO_GRID)
        mp.setattr(
            sweep_mod, "plot_sweep", lambda rows, path, **kw: plots.append((rows, path.name, kw))
        )
        rows = sweep_file(src, out, reference_rays=16, fields=False, plot=True, repeats=1, seed=3)
    return src, out, rows, plots


def _rel_rmse(a, b):
    return float(np.sqrt(((a - b) ** 2).sum() / (b**2).sum()))


def _no_nan(text):
    def refuse(name):
        raise AssertionError(f"{name} in the JSON")

    return json.loads(text, parse_constant=refuse)


def test_lit_sweep_scores_irradiance_against_an_independent_reference(lit_sweep):
    from aobake import lighting
    from aobake.methods import make_options, run_light
    from aobake.methods.bunnell.light import disk_light
    from aobake.pipeline import as_surface

    src, out, rows, _ = lit_sweep
    lit = [r for r in rows if r.quantity == "irradiance"]
    assert [(r.method, r.label) for r in lit] == [
        (m, label) for m, label, _ in light_grid(("embree", "bunnell"))
    ]
    assert [r.quantity for r in rows[: len(rows) - len(lit)]] == ["ao"] * (len(rows) - len(lit))
    # the reference: Embree at 16 samples and 64 paths, seed + 1, cached flat
    (cache,) = out.glob("reference_irradiance_*_samples16_paths64_seed3.npy")
    reference = np.load(cache).reshape(-1, 3)
    surface = as_surface(src)
    job = lighting.prepare(src, surface, "embree", {})
    again = run_light(
        "embree", surface, job.shading, {"light_samples": 16, "indirect_rays": 64, "seed": 4}
    )
    assert np.array_equal(again.direct + again.indirect, reference)
    # each row's numbers from its own irradiance, recomputed (the rows' seed is 3)
    written = {(r["method"], r["label"]): r for r in csv.DictReader((out / "sweep.csv").open())}
    for (method, label, options), row in zip(light_grid(("embree", "bunnell")), lit, strict=True):
        if method == "embree":
            r = run_light("embree", surface, job.shading, {**options, "seed": 3})
        else:
            r = disk_light(surface, job.shading, make_options("bunnell", {}), **options)
        e = r.direct + r.indirect
        expected = _rel_rmse(e, reference)
        assert row.rmse == pytest.approx(expected, rel=1e-9, abs=1e-12)
        assert float(written[(method, label)]["rmse"]) == pytest.approx(expected, rel=1e-9)
        assert written[(method, label)]["quantity"] == "irradiance"
        rms = np.sqrt(np.mean(reference**2))
        assert row.mean_error == pytest.approx(np.mean(e - reference) / rms, rel=1e-9, abs=1e-12)
        assert row.max_abs == pytest.approx(np.abs(e - reference).max() / rms, rel=1e-9)
        assert row.rays == r.n_shadow_rays + r.n_bounce_rays
    emb = {r.label: r.rmse for r in lit if r.method == "embree"}
    assert emb["samples=4 paths=16"] > emb["samples=64 paths=256"]  # more samples, less error
    assert 0 < min(emb.values())  # another seed than the reference's


def test_lit_sweep_has_its_own_pareto_front_plot_and_clean_json(lit_sweep):
    _, out, rows, plots = lit_sweep
    for group in ("ao", "irradiance"):
        mine = [r for r in rows if r.quantity == group]
        for r in mine:
            beaten = any(
                o.seconds <= r.seconds
                and o.rmse <= r.rmse
                and (o.seconds < r.seconds or o.rmse < r.rmse)
                for o in mine
            )
            assert r.pareto == (not beaten)
    data = _no_nan((out / "sweep.json").read_text())
    assert [row["quantity"] for row in data["rows"]] == [r.quantity for r in rows]
    assert data["meta"]["irradiance_reference"] == "embree, 16 samples, 64 paths, seed 4"
    assert [(name, {r.quantity for r in plotted}) for plotted, name, _ in plots] == [
        ("pareto.png", {"ao"}),
        ("pareto_irradiance.png", {"irradiance"}),
    ]
    assert plots[1][2]["front_name"] == "irradiance" and "irradiance" in plots[1][2]["ylabel"]
    text = to_markdown(rows)
    assert text.count("| method | settings |") == 2 and "rel. RMSE" in text


def test_an_unlit_sweep_writes_what_it_wrote_before():
    row = SweepRow("embree", "rays=4", 0.5, 10, 0.1, 0.1, 0.0, 0.2, 0.3, True)
    assert (
        to_csv([row]).splitlines()[0]
        == "method,label,seconds,rays,rmse,mae,mean_error,p99,max_abs,pareto"
    )
    assert list(json.loads(to_json([row], {}))["rows"][0]) == [
        "method", "label", "seconds", "rays", "rmse", "mae", "mean_error", "p99", "max_abs", "pareto",
    ]  # fmt: skip
    assert "Irradiance" not in to_markdown([row])
    lit = SweepRow(
        "embree", "samples=4", 0.5, 10, 0.1, 0.1, 0.0, 0.2, 0.3, True, quantity="irradiance"
    )
    assert to_csv([row, lit]).splitlines()[0].endswith(",pareto,quantity")


def _ground_ply(tmp_path):
    s, _ = scenes.sphere_on_ground(0.5, 1, cells=3)
    src = tmp_path / "s.ply"
    trimesh.Trimesh(s.positions, s.faces, process=False).export(src)
    return src


def test_cli_light_sweep_skips_bunnell_above_its_limit_with_one_warning(tmp_path, monkeypatch):
    import aobake.methods.bunnell.light as disk
    import aobake.tools.sweep as sweep_mod

    src = _ground_ply(tmp_path)
    monkeypatch.setattr(disk, "MAX_VERTICES", 10)
    monkeypatch.setattr(sweep_mod, "default_grid", lambda methods: AO_GRID)
    out = tmp_path / "sw"
    args = [
        "sweep",
        str(src),
        "-o",
        str(out),
        "--reference-rays",
        "16",
        "--repeats",
        "1",
        "--no-fields",
        "--no-plot",
    ]
    r = CliRunner().invoke(main, [*args, "-q", "--light", "point:0,0,3:20"])
    assert r.exit_code == 0, r.output
    assert (
        r.stderr.count("Warning:") == 1
        and "no bunnell irradiance rows" in r.stderr
        and "at most 10" in r.stderr
    )
    rows = list(csv.DictReader((out / "sweep.csv").open()))
    lit = [row for row in rows if row["quantity"] == "irradiance"]
    assert {row["method"] for row in lit} == {"embree"} and len(lit) == len(light_grid(("embree",)))
    assert any(
        row["method"] == "bunnell" and row["quantity"] == "ao" for row in rows
    )  # its AO rows stay
    # a damaged irradiance cache is one line naming it; a bad --light a usage error
    (cache,) = out.glob("reference_irradiance_*.npy")
    np.save(cache, -np.load(cache) - 1.0)
    r = CliRunner().invoke(main, [*args, "-q", "--light", "point:0,0,3:20"])
    assert (
        r.exit_code == 1 and cache.name in r.output and "finite values >= 0; delete it" in r.output
    )
    cache.unlink()
    r = CliRunner().invoke(main, [*args, "-q", "--light", "point:0,0"])
    assert r.exit_code == 2 and "--light" in r.output and "Traceback" not in r.output
    # a light under the ground lights nothing: no irradiance rows, one warning, the AO sweep as without it
    r = CliRunner().invoke(main, [*args, "-q", "--light", "point:0,0,-3:20"])
    assert r.exit_code == 0, r.output
    assert "the reference irradiance is 0 at every vertex" in r.stderr
    assert "Irradiance" not in r.stdout
    assert (out / "sweep.csv").read_text().splitlines()[0].endswith(",pareto")
    # without --light: the unlit sweep's files only
    for f in out.glob("reference_irradiance_*"):
        f.unlink()
    r = CliRunner().invoke(main, [*args, "-q"])
    assert r.exit_code == 0, r.output
    assert (
        not list(out.glob("reference_irradiance_*"))
        and "irradiance" not in (out / "sweep.json").read_text()
    )


def test_irradiance_plot_names_its_front(tmp_path, monkeypatch):
    import matplotlib.pyplot as plt

    from aobake.tools.sweep import mark_pareto, plot_sweep

    closed = []
    real = plt.close
    monkeypatch.setattr(plt, "close", lambda fig: closed.append(fig) or real(fig))
    rows = mark_pareto(
        [
            SweepRow("embree", "a", 0.1, 5, 0.2, 0, 0, 0, 0, quantity="irradiance"),
            SweepRow("bunnell", "b", 0.3, 0, 0.1, 0, 0, 0, 0, quantity="irradiance"),
        ]
    )
    plot_sweep(rows, tmp_path / "p.png", ylabel="relative RMSE", front_name="irradiance")
    (ax,) = closed[0].axes
    assert [t.get_text() for t in ax.get_legend().get_texts()] == [
        "bunnell",
        "embree",
        "Pareto front (irradiance)",
    ]
    assert (
        ax.get_ylabel() == "relative RMSE" and (tmp_path / "p.png").read_bytes()[:4] == b"\x89PNG"
    )


def test_cli_without_matplotlib_says_the_irradiance_plot_was_skipped(tmp_path, monkeypatch):
    import aobake.pipeline
    import aobake.tools.plot as plot

    monkeypatch.setattr(plot, "pyplot", lambda *, required=True: None)
    seen = {}

    def fake_sweep(mesh, out_dir, **kwargs):
        seen.update(kwargs)
        return [
            SweepRow(
                "embree", "samples=4", 0.5, 10, 0.1, 0.1, 0.0, 0.2, 0.3, True, quantity="irradiance"
            )
        ]

    monkeypatch.setattr(aobake.pipeline, "sweep_file", fake_sweep)
    src = _ground_ply(tmp_path)
    r = CliRunner().invoke(
        main, ["sweep", str(src), "-o", str(tmp_path / "sw"), "-q", "--light", "point:0,0,3"]
    )
    assert r.exit_code == 0, r.output
    assert (
        seen["plot"] is False
        and seen["lights"] == ("point:0,0,3",)
        and seen["scene_lights"] is True
    )
    assert "skipping pareto.png" in r.stderr and "skipping pareto_irradiance.png too" in r.stderr
