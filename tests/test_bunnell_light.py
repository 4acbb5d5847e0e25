"""The disk method's light (aobake.methods.bunnell.light): the CLI writes it as for the
reference; closed forms of the exact lights and of an area light's transfer; the
closed-sphere furnace; the box against the ray-traced reference."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from aobake.cli import main
from aobake.io import read_bake

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
    # the reference's ray options are not the disk method's
    r = runner.invoke(main, ["bake", str(CORNELL), "-o", str(out), "--method", "bunnell", "--light-samples", "4"])
    assert r.exit_code == 2 and "--light-samples does not apply to --method bunnell" in r.output + r.stderr
