"""sweep: Pareto marking, outputs, the cached reference."""

from __future__ import annotations

import csv
import json

import numpy as np
import trimesh
from click.testing import CliRunner

from aobake.cli import main
from aobake.testing import scenes
from aobake.tools.sweep import SweepRow, mark_pareto, run_sweep


def _row(label, seconds, rmse):
    return SweepRow("m", label, seconds, 0, rmse, 0.0, 0.0, 0.0, 0.0)


def test_pareto_front():
    rows = mark_pareto(
        [
            _row("a", 1, 0.1),
            _row("b", 2, 0.05),
            _row("c", 3, 0.06),
            _row("d", 0.5, 0.2),
            _row("e", 2, 0.05),
        ]
    )
    assert [r.pareto for r in rows] == [True, True, False, True, True]


def test_run_sweep_scores_against_reference():
    ref = np.linspace(0, 1, 11)
    rows = run_sweep(
        lambda m, o: (ref + o["shift"], 7),
        ref,
        [("m", "s0", {"shift": 0.0}), ("m", "s1", {"shift": 0.1})],
    )
    assert rows[0].rmse == 0.0 and abs(rows[1].rmse - 0.1) < 1e-12
    assert abs(rows[1].mean_error - 0.1) < 1e-12 and abs(rows[1].max_abs - 0.1) < 1e-12
    assert rows[0].rays == 7


def test_cli_sweep_writes_table_csv_json_png_and_caches(tmp_path, monkeypatch):
    s, _ = scenes.sphere_on_ground(0.5, 2, cells=4)
    src = tmp_path / "s.ply"
    trimesh.Trimesh(s.positions, s.faces, process=False).export(src)
    out = tmp_path / "sweep"
    r = CliRunner().invoke(
        main,
        [
            "sweep",
            str(src),
            "-o",
            str(out),
            "--reference-rays",
            "256",
            "--repeats",
            "1",
            "-q",
            "--no-fields",
        ],
    )
    assert r.exit_code == 0, r.output
    assert r.stdout.startswith("| method | settings |")
    rows = list(csv.DictReader((out / "sweep.csv").open()))
    assert len(rows) == len(r.stdout.strip().splitlines()) - 2
    data = json.loads((out / "sweep.json").read_text())
    assert data["meta"]["n_vertices"] == s.n_vertices and len(data["rows"]) == len(rows)
    assert (out / "pareto.png").read_bytes()[:4] == b"\x89PNG"
    # more rays, less error (the reference is independent: another seed)
    emb = {row["label"]: float(row["rmse"]) for row in rows if row["method"] == "embree"}
    assert emb["rays=4"] > emb["rays=64"] > emb["rays=1024"]
    # second run: the reference comes from the cache
    import aobake.methods.embree.estimator as rt

    calls = []
    real = rt.estimate  # every Embree bake, the grid's and the reference's, ends here
    monkeypatch.setattr(
        rt,
        "estimate",
        lambda surface, options, *a, **k: calls.append((options.n_rays, options.seed))
        or real(surface, options, *a, **k),
    )
    r2 = CliRunner().invoke(
        main,
        [
            "sweep",
            str(src),
            "-o",
            str(out),
            "--reference-rays",
            "256",
            "--repeats",
            "1",
            "-q",
            "--no-plot",
            "--no-fields",
        ],
    )
    assert r2.exit_code == 0
    assert calls and (256, 1) not in calls  # the reference uses seed + 1


def test_sweep_field_rows_score_the_ground(tmp_path, monkeypatch):
    import aobake.tools.sweep as sweep_mod

    monkeypatch.setattr(
        sweep_mod,
        "field_grid",
        lambda: [
            ("field", "N=2", {"resolution": 2, "radial_samples": 4, "raster_size": 8}),
            ("field", "N=6", {"resolution": 6, "radial_samples": 8, "raster_size": 16}),
        ],
    )
    s = scenes.sphere(0.5, 2)
    src = tmp_path / "ball.ply"
    trimesh.Trimesh(s.positions, s.faces, process=False).export(src)
    from aobake.pipeline import sweep_file

    rows = sweep_file(
        src, tmp_path / "sw", reference_rays=256, methods=("embree",), plot=True, repeats=1
    )
    field = [r for r in rows if r.method == "field"]
    assert [r.label for r in field] == ["N=2", "N=6"]
    # a finer field is closer to ray-traced AO on the ground, and both are informative
    assert field[1].rmse < field[0].rmse < 0.2
    assert (tmp_path / "sw" / "pareto.png").exists()
