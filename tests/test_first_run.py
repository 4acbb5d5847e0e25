"""The first run: compiling kernels is announced, kept out of reported times, and
`aobake warm-up` compiles what the commands need."""

from __future__ import annotations

import io
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from aobake import pipeline
from aobake.cli import main
from aobake.methods import MethodResult
from aobake.progress import COMPILING, CompileWatch


def _fresh_kernel():
    """A numba function no cache has seen: its first call compiles (a few tenths of a s)."""
    from numba import njit

    def total(x):
        s = 0.0
        for i in range(x.shape[0]):
            s += np.sin(x[i]) * np.cos(x[i])
        return s

    return njit(cache=False)(total)


def test_compile_watch_sees_a_compile_once():
    kernel = _fresh_kernel()
    x = np.linspace(0.0, 1.0, 10)
    stream = io.StringIO()
    with CompileWatch(stream) as watch:
        t0 = time.perf_counter()
        first = kernel(x)
        wall = time.perf_counter() - t0
        seconds, count = watch.seconds, watch.count
        assert kernel(x) == first  # compiled now: no second compile
        assert kernel(x + 1.0) == pytest.approx(np.sum(np.sin(x + 1) * np.cos(x + 1)))
    assert count >= 1 and watch.count == count
    assert 0.0 < seconds <= wall and watch.seconds == seconds
    assert stream.getvalue() == COMPILING + "\n"
    kernel(np.arange(3))  # after the watch ended: an int64 compile it does not see
    assert watch.count == count


def test_compile_watch_silent_without_a_stream_and_when_nothing_compiles(capsys):
    kernel = _fresh_kernel()
    with CompileWatch() as watch:
        kernel(np.ones(4))
    assert watch.count >= 1
    stream = io.StringIO()
    with CompileWatch(stream) as again:
        kernel(np.ones(5))
    assert again.count == 0 and again.seconds == 0.0 and stream.getvalue() == ""
    assert capsys.readouterr().err == ""


@pytest.fixture
def compiling_compute(monkeypatch):
    """``pipeline._compute`` replaced by one that compiles a fresh kernel, then sleeps
    0.05 s (the "work"), and returns ao = 0.5 everywhere with 1000 rays."""
    def compute(surface, method, options, progress, vertices=None, ground=None):
        kernel = _fresh_kernel()
        kernel(np.ones(3))
        time.sleep(0.05)
        return MethodResult(np.full(surface.n_vertices, 0.5), 1000).ao, 1000, 0, {}

    monkeypatch.setattr(pipeline, "_compute", compute)


@pytest.fixture
def cube_ply(tmp_path):
    import trimesh

    path = tmp_path / "cube.ply"
    trimesh.creation.box().export(path)
    return path


def test_bake_time_and_rate_exclude_compiling(compiling_compute, cube_ply, tmp_path):
    t0 = time.perf_counter()
    report = pipeline.bake_file(cube_ply, tmp_path / "out.ply")
    wall = time.perf_counter() - t0
    assert report.compile_seconds > 0.0
    # the work (0.05 s) without the compile, which took longer than it
    assert 0.05 <= report.seconds < 0.05 + 0.5 * report.compile_seconds
    assert report.seconds + report.compile_seconds <= wall
    line = report.summary()
    rate = 1000 / report.seconds / 1e6
    assert f"({rate:.2f} M rays/s)" in line
    assert f"(+ {report.compile_seconds:.1f} s compiling kernels, first run only)" in line


def test_cli_says_it_compiles_unless_quiet(compiling_compute, cube_ply, tmp_path):
    runner = CliRunner()
    result = runner.invoke(main, ["bake", str(cube_ply), "-o", str(tmp_path / "a.ply")])
    assert result.exit_code == 0, result.output
    lines = result.stderr.splitlines()
    assert lines[0] == COMPILING and len(lines) == 2
    assert "compiling kernels, first run only) ->" in lines[1]
    quiet = runner.invoke(main, ["bake", str(cube_ply), "-o", str(tmp_path / "b.ply"), "--quiet"])
    assert quiet.exit_code == 0 and quiet.stderr == "" and quiet.stdout == ""


def test_nothing_compiled_nothing_said(cube_ply, tmp_path, monkeypatch):
    monkeypatch.setattr(pipeline, "_compute", lambda s, m, o, p, v=None, g=None: (np.ones(s.n_vertices), 0, 0, {}))
    result = CliRunner().invoke(main, ["bake", str(cube_ply), "-o", str(tmp_path / "a.ply")])
    assert result.exit_code == 0
    assert COMPILING not in result.stderr and "compiling" not in result.stderr


def _specialisations() -> dict:
    """{kernel: compiled signatures} of every numba function aobake has loaded."""
    from numba.core.registry import CPUDispatcher

    out = {}
    for name, module in list(sys.modules.items()):
        if name.startswith("aobake"):
            for attr, value in vars(module).items():
                if isinstance(value, CPUDispatcher):
                    out[f"{name}.{attr}"] = set(value.overloads)
    return out


def test_warm_up_compiles_what_the_commands_need(tmp_path):
    """After `aobake warm-up`, the commands on another mesh need no kernel it did not
    compile (or load from the cache)."""
    runner = CliRunner()
    result = runner.invoke(main, ["warm-up"])
    assert result.exit_code == 0, result.output
    assert result.stderr.splitlines()[-1].startswith("warm-up: bake --method embree, bake --method bunnell")
    before = _specialisations()
    assert before  # it loaded kernels
    import trimesh

    from aobake.testing import scenes

    s, _ = scenes.sphere_on_ground(0.5, 1, gap=0.0, cells=5)
    mesh = tmp_path / "scene.ply"
    trimesh.Trimesh(s.positions, s.faces, process=False).export(mesh)
    trimesh.creation.icosphere(1).export(tmp_path / "ball.ply")
    for args in (
        ["bake", str(mesh), "-o", str(tmp_path / "e.ply")],
        ["bake", str(mesh), "-o", str(tmp_path / "b.usda"), "--method", "bunnell"],
        ["bake", str(mesh), "-o", str(tmp_path / "u.ply"), "--method", "bunnell", "--measure", "uniform"],
        ["bake", str(mesh), "-o", str(tmp_path / "p.ply"), "--method", "bunnell", "--passes", "3"],
        ["field", str(tmp_path / "ball.ply"), "-o", str(tmp_path / "ball.npz"), "--resolution", "4"],
        ["bake", str(mesh), "-o", str(tmp_path / "f.ply"), "--field", f"{tmp_path / 'ball.npz'}@0,0,1"],
        ["preview", str(tmp_path / "e.ply"), "-o", str(tmp_path / "e.png"), "--size", "32"],
        ["bake", str(mesh), "-o", str(tmp_path / "l.ply"), "--light", "distant:1,2,1:3", "--color", "--rays", "8"],
        ["bake", str(Path(__file__).resolve().parents[1] / "data" / "cornell_box.usda"), "-o",
         str(tmp_path / "c.ply"), "--rays", "8", "--light-samples", "4", "--indirect-rays", "4"],
        ["bake", str(Path(__file__).resolve().parents[1] / "data" / "cornell_box.usda"), "-o",
         str(tmp_path / "cb.ply"), "--method", "bunnell"],
    ):
        result = runner.invoke(main, args)
        assert result.exit_code == 0, (args, result.output)
        assert COMPILING not in result.stderr, args
    after = _specialisations()
    new = {k: v - before.get(k, set()) for k, v in after.items() if v - before.get(k, set())}
    assert not new
