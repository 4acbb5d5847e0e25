"""compare: statistics against hand-computed values, CLI behaviour, JSON and plot outputs."""

from __future__ import annotations

import builtins
import json

import numpy as np
import pytest
from click.testing import CliRunner

from aobake.cli import main
from aobake.errors import AobakeError, InputError
from aobake.tools.compare import compare_ao, plot_compare


def test_statistics_by_hand():
    a = np.array([0.0, 0.5, 1.0, 1.0])
    b = np.array([0.1, 0.5, 0.8, 1.0])
    r = compare_ao(a, b, threshold=0.15, worst=2, positions=np.arange(12.0).reshape(4, 3))
    err = b - a
    assert r.rmse == pytest.approx(np.sqrt((0.01 + 0.04) / 4))
    assert r.mae == pytest.approx(0.3 / 4)
    assert r.mean_error == pytest.approx(-0.1 / 4)
    assert r.max_abs == pytest.approx(0.2)
    assert r.p50 == pytest.approx(np.percentile(np.abs(err), 50))
    assert r.above == pytest.approx(0.25)
    assert [w.index for w in r.worst] == [2, 0]
    assert r.worst[0].position == (6.0, 7.0, 8.0)
    assert r.worst[0].error == pytest.approx(-0.2)


def test_identical_bakes_have_zero_error():
    a = np.random.default_rng(0).random(100)
    r = compare_ao(a, a.copy())
    assert r.rmse == r.max_abs == r.above == 0.0


def test_mismatched_counts_refused():
    with pytest.raises(InputError, match=r"^b: has 3 vertices but a has 4"):
        compare_ao(np.zeros(4), np.zeros(3))
    with pytest.raises(InputError, match="non-finite"):
        compare_ao(np.zeros(2), np.array([0.0, np.nan]))


def test_cli_compare_npy_json_plot(tmp_path):
    a, b = tmp_path / "a.npy", tmp_path / "b.npy"
    np.save(a, np.linspace(0, 1, 50))
    np.save(b, np.linspace(0, 1, 50) * 0.9)
    result = CliRunner().invoke(
        main,
        [
            "compare",
            str(a),
            str(b),
            "--json",
            str(tmp_path / "r.json"),
            "--plot",
            str(tmp_path / "r.png"),
        ],
    )
    assert result.exit_code == 0, result.output
    assert "RMSE" in result.stdout and "b.npy against a.npy" in result.stdout
    data = json.loads((tmp_path / "r.json").read_text())
    assert data["n_vertices"] == 50 and data["max_abs"] == pytest.approx(0.1)
    assert (tmp_path / "r.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_cli_compare_mismatch_is_one_line(tmp_path):
    np.save(tmp_path / "a.npy", np.zeros(4))
    np.save(tmp_path / "b.npy", np.zeros(5))
    result = CliRunner().invoke(main, ["compare", str(tmp_path / "a.npy"), str(tmp_path / "b.npy")])
    assert result.exit_code == 1
    assert result.stderr == (
        "Error: b.npy: has 5 vertices but a.npy has 4; compare bakes of the same mesh\n"
    )


def test_cli_compare_mesh_bakes_report_positions(tmp_path):
    import trimesh

    from aobake.testing import scenes

    s, _ = scenes.sphere_on_ground(0.5, 2, cells=4)
    src = tmp_path / "s.ply"
    trimesh.Trimesh(s.positions, s.faces, process=False).export(src)
    r = CliRunner()
    assert (
        r.invoke(
            main, ["bake", str(src), "-o", str(tmp_path / "hi.ply"), "--rays", "256", "-q"]
        ).exit_code
        == 0
    )
    assert (
        r.invoke(
            main, ["bake", str(src), "-o", str(tmp_path / "lo.usda"), "--rays", "8", "-q"]
        ).exit_code
        == 0
    )
    result = r.invoke(
        main, ["compare", str(tmp_path / "hi.ply"), str(tmp_path / "lo.usda"), "--worst", "3"]
    )
    assert result.exit_code == 0, result.output
    assert "worst vertices" in result.stdout and result.stdout.count("(") >= 3


def test_plot_without_matplotlib_is_a_clear_error(tmp_path, monkeypatch):
    real_import = builtins.__import__

    def no_mpl(name, *args, **kwargs):
        if name.startswith("matplotlib"):
            raise ImportError("no matplotlib")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_mpl)
    with pytest.raises(AobakeError, match=r"needs matplotlib, which is not installed"):
        plot_compare(np.zeros(3), np.zeros(3), tmp_path / "p.png")
    assert list(tmp_path.iterdir()) == []


def test_plot_needs_png_suffix(tmp_path):
    np.save(tmp_path / "a.npy", np.zeros(4))
    result = CliRunner().invoke(
        main,
        [
            "compare",
            str(tmp_path / "a.npy"),
            str(tmp_path / "a.npy"),
            "--plot",
            str(tmp_path / "p.jpg"),
        ],
    )
    assert result.exit_code == 1 and "use a .png suffix" in result.stderr
