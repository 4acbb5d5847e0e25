"""Messages: a failing command prints its one ``Error:`` line and nothing else (warnings
from numpy, trimesh and USD are held back, shown only on success); the names users see
(``mean_error``, per-method defaults); what `sweep` and `make bake` say."""

from __future__ import annotations

import json
import logging
import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import aobake.pipeline
from aobake.checks import check_result
from aobake.cli import main
from aobake.errors import AobakeError, InputError, NumericalError
from aobake.progress import COMPILING


def _said(result) -> str:
    """What a command printed, without the one-off "compiling kernels" notice of a cold
    numba cache (a progress note, printed when compiling starts)."""
    return "".join(line for line in result.output.splitlines(True) if line.rstrip("\n") != COMPILING)

REPO = Path(__file__).resolve().parents[1]


_MESH = """def Mesh "m" {
    point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
    int[] faceVertexCounts = [3]
    int[] faceVertexIndices = [0, 1, 2]
}
"""


def _usd_with_missing_sublayer(path: Path, mesh: bool) -> Path:
    """A stage whose sublayer is missing: USD prints a warning on its stderr when it opens."""
    path.write_text('#usda 1.0\n(\n    subLayers = [@missing.usda@]\n)\n' + (_MESH if mesh else 'def Xform "x" {}\n'))
    return path


def test_usd_stderr_is_held_back_when_the_command_fails(tmp_path):
    """Run as a process: USD writes to file descriptor 2 directly, past Python."""
    src = _usd_with_missing_sublayer(tmp_path / "warn.usda", mesh=False)
    proc = subprocess.run(
        [sys.executable, "-m", "aobake", "bake", str(src), "-o", str(tmp_path / "o.ply")],
        capture_output=True, text=True, env=dict(os.environ, PYTHONPATH=str(REPO)),
    )
    assert proc.returncode == 1
    assert proc.stderr == "Error: warn.usda: no visible UsdGeom.Mesh in the stage\n"


def test_usd_stderr_is_shown_as_one_warning_line_on_success(tmp_path):
    src = _usd_with_missing_sublayer(tmp_path / "warn.usda", mesh=True)
    proc = subprocess.run(
        [sys.executable, "-m", "aobake", "bake", str(src), "-o", str(tmp_path / "o.ply"), "--rays", "4", "-q"],
        capture_output=True, text=True, env=dict(os.environ, PYTHONPATH=str(REPO)),
    )
    assert proc.returncode == 0, proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line != COMPILING]
    assert len(lines) == 1 and lines[0].startswith("Warning: warn.usda: Could not load sublayer @missing.usda@")


@pytest.mark.parametrize("source", ["numpy", "trimesh"])
def test_warnings_are_held_back_when_the_command_fails(runner, scene_ply, tmp_path, monkeypatch, source):
    real = aobake.pipeline.as_surface

    def noisy(mesh, time=None, prepare=None):  # as_surface's signature (time: USD inputs)
        if source == "numpy":
            with np.errstate(divide="warn"):
                np.float64(1.0) / np.zeros(1)
        else:
            logging.getLogger("trimesh").warning("face normals did not match")
        real(mesh, time, prepare)
        raise InputError(mesh, "refused after the warning")

    monkeypatch.setattr(aobake.pipeline, "as_surface", noisy)
    result = runner.invoke(main, ["bake", str(scene_ply), "-o", str(tmp_path / "o.ply"), "--rays", "4"])
    assert result.exit_code == 1
    assert _said(result) == "Error: scene.ply: refused after the warning\n"


def test_warnings_are_shown_once_each_after_success(runner, scene_ply, tmp_path, monkeypatch):
    real = aobake.pipeline.as_surface

    def noisy(mesh, time=None, prepare=None):
        for _ in range(3):
            warnings.warn("odd  but\nfine", UserWarning)  # noqa: B028
        return real(mesh, time, prepare)

    monkeypatch.setattr(aobake.pipeline, "as_surface", noisy)
    result = runner.invoke(main, ["bake", str(scene_ply), "-o", str(tmp_path / "o.ply"), "--rays", "4", "-q"])
    assert result.exit_code == 0, result.output
    assert _said(result) == "Warning: odd but fine\n"


def test_bunnell_non_finite_error_is_one_line_naming_the_file(runner, scene_ply, tmp_path, monkeypatch):
    import aobake.methods.bunnell.estimator as estimator

    real = estimator.combine_passes

    def broken(occlusion, combine):
        ao = real(occlusion, combine).copy()
        ao[3] = np.nan
        return ao

    monkeypatch.setattr(estimator, "combine_passes", broken)
    result = runner.invoke(main, ["bake", str(scene_ply), "-o", str(tmp_path / "o.ply"), "--method", "bunnell"])
    assert result.exit_code == 1
    assert _said(result) == (
        "Error: scene.ply: bunnell: 1 values of ao outside [0.0, 1.0] or non-finite (first: vertex 3, value nan)\n"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.ply"]


def test_check_result_names_one_value_of_a_2d_array():
    values = np.zeros((5, 4))
    values[2, 1] = np.inf
    with pytest.raises(NumericalError) as info:
        check_result(values, "sums", lower=0.0, upper=1.0, method="bunnell")
    assert str(info.value) == "bunnell: 1 values of sums outside [0.0, 1.0] or non-finite (first: vertex 2, value inf)"


# -- names ----------------------------------------------------------------------------------


def test_compare_says_mean_error_not_bias(runner, scene_ply, tmp_path):
    a, b = tmp_path / "a.ply", tmp_path / "b.ply"
    for out, seed in ((a, "0"), (b, "1")):
        args = ["bake", str(scene_ply), "-o", str(out), "--rays", "8", "--seed", seed, "-q"]
        assert runner.invoke(main, args).exit_code == 0
    result = runner.invoke(main, ["compare", str(a), str(b), "--json", str(tmp_path / "r.json")])
    assert result.exit_code == 0, result.output
    assert "bias" not in result.output and "mean err" in result.output
    data = json.loads((tmp_path / "r.json").read_text())
    assert "bias" not in data
    from aobake.io import read_bake

    assert data["mean_error"] == pytest.approx(float(np.mean(read_bake(b) - read_bake(a))), abs=1e-12)


def test_sweep_tables_say_mean_error():
    from aobake.tools import sweep

    row = sweep.SweepRow(method="embree", label="x", seconds=1.0, rays=0, rmse=0.1, mae=0.1, mean_error=-0.05, p99=0.2, max_abs=0.3)
    assert sweep.to_csv([row]).splitlines()[0] == "method,label,seconds,rays,rmse,mae,mean_error,p99,max_abs,pareto"
    assert "| mean error |" in sweep.to_markdown([row]) and "bias" not in sweep.to_markdown([row])
    for md in (REPO / "report").glob("*.md"):
        assert "| bias |" not in md.read_text(), md


def test_help_shows_per_method_and_per_view_defaults(runner, monkeypatch):
    import dataclasses

    import aobake.methods as methods
    from aobake.cli import method_options
    from aobake.options import option

    text = " ".join(runner.invoke(main, ["preview", "--help"], terminal_width=200).output.split())
    assert "[default: the view's: front -90, side 0, top -90, iso -55]" in text
    assert "[default: the view's: front 10, side 10, top 89, iso 30]" in text
    text = " ".join(runner.invoke(main, ["bake", "--help"], terminal_width=200).output.split())
    assert "embree: Random seed [default: 0]" in text
    assert "Ignore geometry farther than this from the vertex (mesh units) [default: unbounded]" in text
    assert "[default: off]" in text  # --tolerance
    # an unbounded number is a FLOAT, with no "x<=None" range
    assert "--exposure FLOAT " in text and "None]" not in text
    # an option two methods take with different defaults shows both
    real = methods.options_class

    @dataclasses.dataclass(frozen=True)
    class Other:
        n_rays: int = option(16, "Rays per vertex.", kind=int, flag="rays", low=1)

    monkeypatch.setattr(methods, "METHODS", ("embree", "other"))
    monkeypatch.setattr(methods, "options_class", lambda m: Other if m == "other" else real(m))
    import click

    @click.command()
    @method_options
    def cmd(**kw):
        pass

    text = " ".join(CliRunner().invoke(cmd, ["--help"], terminal_width=200).output.split())
    assert "[default: embree 256, other 16]" in text


# -- sweep without matplotlib ----------------------------------------------------------------


def _no_matplotlib(monkeypatch):
    import aobake.tools.plot as plot

    def pyplot(*, required=True):
        if required:
            raise AobakeError("plotting needs matplotlib, which is not installed (pip install matplotlib)")
        return None

    monkeypatch.setattr(plot, "pyplot", pyplot)


def test_sweep_checks_matplotlib_before_any_work(tmp_path, monkeypatch):
    _no_matplotlib(monkeypatch)
    called = []
    monkeypatch.setattr(aobake.pipeline, "as_surface", lambda m: called.append(m))
    with pytest.raises(AobakeError, match="needs matplotlib"):
        aobake.pipeline.sweep_file(tmp_path / "none.ply", tmp_path / "sw", plot=True)
    assert called == []


def test_sweep_cli_without_matplotlib_writes_the_tables_and_says_the_plot_was_skipped(runner, scene_ply, tmp_path, monkeypatch):
    _no_matplotlib(monkeypatch)
    seen = {}

    def fake_sweep(mesh, out_dir, **kwargs):
        seen.update(kwargs)
        return []

    monkeypatch.setattr(aobake.pipeline, "sweep_file", fake_sweep)
    result = runner.invoke(main, ["sweep", str(scene_ply), "-o", str(tmp_path / "sw"), "-q"])
    assert result.exit_code == 0, result.output
    assert seen["plot"] is False
    assert "matplotlib is not installed; writing sweep.csv and sweep.json, skipping pareto.png" in result.output
    assert "aobake[plot]" not in result.output


# -- make bake ---------------------------------------------------------------------------------


@pytest.mark.skipif(shutil.which("make") is None, reason="needs GNU make")
def test_make_bake_says_what_it_baked(tmp_path, scene_ply):
    inputs = tmp_path / "in"
    inputs.mkdir()
    shutil.copy(scene_ply, inputs / "a.ply")
    stamp = tmp_path / "stamp"
    stamp.touch()
    aobake_cmd = f"env PYTHONPATH={REPO} {sys.executable} -m aobake"
    args = [
        "make", "--no-print-directory", "-C", str(REPO), "bake", f"IN={inputs}", f"OUT={tmp_path / 'out'}",
        f"STAMP={stamp}", f"AOBAKE={aobake_cmd}", "BAKE_FLAGS=--quiet --rays 4",
    ]
    first = subprocess.run(args, capture_output=True, text=True)
    assert first.returncode == 0, first.stderr
    out = tmp_path / "out"
    assert first.stdout == f"baked {inputs / 'a.ply'} -> {out}/a.ply, {out}/a.usda\n"
    second = subprocess.run(args, capture_output=True, text=True)
    assert second.stdout == f"{out}/ is up to date (1 meshes)\n"
