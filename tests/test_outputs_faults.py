"""Outputs and faults: every output (PLY, USD, field .npz, compare JSON, preview PNG,
sweep) fails in one line naming the output, exits non-zero, and leaves nothing behind;
SIGTERM is handled like Ctrl-C; no NaN in JSON; outputs never overwrite inputs."""

from __future__ import annotations

import dataclasses
import errno
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh

import aobake.io.common as common
from aobake.cli import main
from aobake.io import read_bake
from aobake.testing import scenes


@pytest.fixture(scope="module")
def field_npz(tmp_path_factory) -> Path:
    """The smallest field file: a unit box, one texel per face edge, 3 radial samples."""
    from aobake.methods.fields import fit_field, save_field

    path = tmp_path_factory.mktemp("field") / "box.npz"
    save_field(fit_field(scenes.box((1.0, 1.0, 1.0)), resolution=1, radial_samples=3, raster_size=8), path)
    return path


def _files(directory: Path) -> list[str]:
    """Every name in ``directory``, hidden temporary files included."""
    return sorted(p.name for p in directory.iterdir())


def _said(result) -> str:
    """What a command printed, without the cold-cache notice ("compiling kernels ...")."""
    from aobake.progress import COMPILING

    return "".join(line for line in result.output.splitlines(keepends=True) if not line.startswith(COMPILING))


def _one_error_line(result, name: str, problem: str) -> None:
    assert result.exit_code == 1, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    assert _said(result).strip() == f"Error: {name}: {problem}", result.output


def _bake(scene, out, *extra):
    return ["bake", str(scene), "-o", str(out), "--rays", "8", "-q", *extra]


# -- ENOSPC / EROFS for every output --------------------------------------------------


def _disk_full(monkeypatch):
    """Writes fail when the finished temporary file is renamed into place (a full disk
    or a directory that vanished would fail there or earlier)."""

    real = os.replace

    def replace(src, dst):
        if not Path(src).name.startswith("."):  # not aobake's (numba's cache index)
            return real(src, dst)
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(common.os, "replace", replace)


def _read_only(monkeypatch):
    """Creating the temporary file fails (a read-only file system; root ignores modes)."""

    real = tempfile.mkstemp

    def mkstemp(*args, prefix=None, **kwargs):
        if not (prefix or "").startswith("."):  # not aobake's
            return real(*args, prefix=prefix, **kwargs)
        raise OSError(errno.EROFS, os.strerror(errno.EROFS))

    monkeypatch.setattr(tempfile, "mkstemp", mkstemp)


FAULTS = {"disk full": (_disk_full, os.strerror(errno.ENOSPC)), "read-only": (_read_only, os.strerror(errno.EROFS))}


@pytest.mark.parametrize("fault", FAULTS)
@pytest.mark.parametrize("suffix", [".ply", ".usda", ".usdc"])
def test_bake_write_failure_names_the_output(runner, scene_ply, tmp_path, monkeypatch, fault, suffix):
    out = tmp_path / f"o{suffix}"
    before = _files(tmp_path)
    FAULTS[fault][0](monkeypatch)
    result = runner.invoke(main, _bake(scene_ply, out))
    _one_error_line(result, out.name, f"cannot write ({FAULTS[fault][1]})")
    assert _files(tmp_path) == before


@pytest.mark.parametrize("fault", FAULTS)
def test_two_outputs_fail_together(runner, scene_ply, tmp_path, monkeypatch, fault):
    before = _files(tmp_path)
    FAULTS[fault][0](monkeypatch)
    result = runner.invoke(main, _bake(scene_ply, tmp_path / "a.ply") + ["-o", str(tmp_path / "a.usda")])
    assert result.exit_code == 1 and _said(result).count("\n") == 1, result.output
    assert re.fullmatch(r"Error: a\.(ply|usda): cannot write \(.*\)\n", _said(result))
    assert _files(tmp_path) == before


@pytest.mark.parametrize("fault", FAULTS)
def test_field_write_failure(runner, tmp_path, monkeypatch, fault):
    occluder = tmp_path / "box.ply"
    box = scenes.box((1.0, 1.0, 1.0))
    trimesh.Trimesh(box.positions, box.faces, process=False).export(occluder)
    before = _files(tmp_path)
    FAULTS[fault][0](monkeypatch)
    args = ["field", str(occluder), "-o", str(tmp_path / "f.npz"), "--resolution", "1"]
    result = runner.invoke(main, args + ["--radial-samples", "3", "--raster-size", "8", "-q"])
    _one_error_line(result, "f.npz", f"cannot write ({FAULTS[fault][1]})")
    assert _files(tmp_path) == before


@pytest.mark.parametrize("fault", FAULTS)
@pytest.mark.parametrize("kind", ["json", "render", "preview"])
def test_compare_and_preview_write_failures(runner, scene_ply, tmp_path, monkeypatch, fault, kind):
    a, b = tmp_path / "a.ply", tmp_path / "b.ply"
    assert runner.invoke(main, _bake(scene_ply, a)).exit_code == 0
    assert runner.invoke(main, _bake(scene_ply, b, "--seed", "1")).exit_code == 0
    before = _files(tmp_path)
    FAULTS[fault][0](monkeypatch)
    out = tmp_path / ("r.json" if kind == "json" else "r.png")
    if kind == "preview":
        args = ["preview", str(a), "-o", str(out), "--size", "32"]
    else:
        args = ["compare", str(a), str(b), f"--{kind}", str(out)]
    result = runner.invoke(main, args)
    assert result.exit_code == 1, result.output
    assert result.output.strip().splitlines()[-1] == f"Error: {out.name}: cannot write ({FAULTS[fault][1]})"
    assert "Traceback" not in result.output
    assert _files(tmp_path) == before


def test_sweep_write_failure(runner, scene_ply, tmp_path, monkeypatch):
    """The first sweep output (the reference cache) fails: one line naming it."""
    _disk_full(monkeypatch)
    out = tmp_path / "sw"
    args = ["sweep", str(scene_ply), "-o", str(out), "--reference-rays", "16", "--no-plot", "-q"]
    result = runner.invoke(main, args)
    assert result.exit_code == 1, result.output
    line = _said(result).strip()
    assert line.startswith("Error: reference_") and line.endswith(f"cannot write ({os.strerror(errno.ENOSPC)})")
    assert _files(out) == []


# -- names -----------------------------------------------------------------------------


@pytest.mark.parametrize("suffix", [".ply", ".usda"])
def test_long_output_name_whose_temporary_sibling_would_exceed_255_bytes(runner, scene_ply, tmp_path, suffix):
    out = tmp_path / ("a" * (255 - len(suffix)) + suffix)
    result = runner.invoke(main, _bake(scene_ply, out))
    assert result.exit_code == 0, result.output
    assert read_bake(out).shape == (trimesh.load(scene_ply, process=False).vertices.shape[0],)
    assert _files(tmp_path) == sorted([out.name, scene_ply.name])


def test_temporary_prefix_fits_in_255_bytes_with_multibyte_names():
    path = Path("é" * 127 + ".usda")  # 254 bytes
    name = common._temporary_prefix(path) + "x" * 8 + path.suffix
    assert len(os.fsencode(name)) <= 255 - 7  # USD adds ".XXXXXX" for its own temporary


def test_dot_as_output_is_refused_by_name(runner, scene_ply, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result = runner.invoke(main, _bake(scene_ply, "."))
    assert result.exit_code == 1
    assert result.output.strip() == "Error: .: is a directory; give an output file such as out.ply"


def test_atomic_write_does_not_nest(tmp_path):
    """A writer called on the temporary file of an atomic write writes into it: one
    temporary file, renamed once."""
    out = tmp_path / "o.ply"
    with common.atomic_write(out) as tmp, common.atomic_write(tmp) as inner:
        assert inner == tmp
        inner.write_text("x")
        assert _files(tmp_path) == [tmp.name]
    assert _files(tmp_path) == ["o.ply"] and out.read_text() == "x"


# -- SIGTERM -----------------------------------------------------------------------------

_SLOW_WRITE = """
import sys, time
from pathlib import Path
import aobake.io
real = aobake.io.write_bake
def slow(path, *args, **kwargs):
    real(path, *args, **kwargs)
    Path(sys.argv[1]).write_text("writing")
    time.sleep(60)
aobake.io.write_bake = slow
from aobake.cli import main
sys.exit(main(sys.argv[2:]))
"""


def test_sigterm_during_the_write_phase_leaves_nothing(scene_ply, tmp_path):
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    marker = tmp_path / "marker"
    args = _bake(scene_ply, out_dir / "o.ply") + ["-o", str(out_dir / "o.usda")]
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    proc = subprocess.Popen(
        [sys.executable, "-c", _SLOW_WRITE, str(marker), *args], stderr=subprocess.PIPE, text=True, env=env
    )
    deadline = time.monotonic() + 120
    while not marker.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert marker.exists(), proc.communicate()[1]
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert "Traceback" not in err
    assert _files(out_dir) == []


def test_signals_are_held_while_a_temporary_file_is_created(tmp_path):
    """SIGTERM arriving while the temporary file is made is delivered after the cleanup
    handler is in place: no temporary file survives."""
    got = []

    def on_term(signum, frame):
        got.append(signum)
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGTERM, on_term)
    real = tempfile.mkstemp

    def mkstemp(*args, **kwargs):
        made = real(*args, **kwargs)
        os.kill(os.getpid(), signal.SIGTERM)  # between creation and the cleanup handler
        return made

    try:
        tempfile.mkstemp = mkstemp
        with pytest.raises(KeyboardInterrupt), common.atomic_write(tmp_path / "o.ply") as tmp:
            tmp.write_text("never")
    finally:
        tempfile.mkstemp = real
        signal.signal(signal.SIGTERM, old)
    assert got == [signal.SIGTERM]
    assert _files(tmp_path) == []


# -- JSON, caches, existing files, inputs ---------------------------------------------------


def test_compare_threshold_nan_is_refused(runner, scene_ply, tmp_path):
    a = tmp_path / "a.ply"
    assert runner.invoke(main, _bake(scene_ply, a)).exit_code == 0
    result = runner.invoke(main, ["compare", str(a), str(a), "--threshold", "nan", "--json", str(tmp_path / "r.json")])
    assert result.exit_code == 2 and "nan is not a finite number" in result.output
    assert not (tmp_path / "r.json").exists()


def test_json_never_holds_nan():
    from aobake.tools import sweep
    from aobake.tools.compare import compare_ao

    report = compare_ao(np.zeros(3), np.zeros(3), threshold=0.1)
    assert json.loads(report.to_json())["mean_error"] == 0.0
    nan_report = dataclasses.replace(report, rmse=float("nan"))
    with pytest.raises(ValueError):
        nan_report.to_json()
    row = sweep.SweepRow(
        method="embree", label="x", seconds=1.0, rays=0, rmse=float("nan"), mae=0.0,
        mean_error=0.0, p99=0.0, max_abs=0.0,
    )
    with pytest.raises(ValueError):
        sweep.to_json([row], {})


@pytest.mark.parametrize(
    "cache, problem",
    [
        (lambda n: np.full(n, np.nan), "not a reference of {n} finite values in [0, 1]; delete it to recompute"),
        (lambda n: np.ones(n + 1), "not a reference of {n} finite values in [0, 1]; delete it to recompute"),
        (lambda n: np.ones((n, 2)), "expected a 1-D float array, got shape ({n}, 2) dtype float64"),
        (lambda n: np.array([{"x": 1}], dtype=object), "not a readable .npy array"),
    ],
)
def test_sweep_cache_is_validated(runner, scene_ply, tmp_path, cache, problem):
    from aobake.pipeline import as_surface, sweep_key

    surface = as_surface(scene_ply)
    out = tmp_path / "sw"
    out.mkdir()
    name = f"reference_{sweep_key(surface)}_rays16_seed0.npy"
    np.save(out / name, cache(surface.n_vertices), allow_pickle=True)
    args = ["sweep", str(scene_ply), "-o", str(out), "--reference-rays", "16", "--no-plot", "-q"]
    result = runner.invoke(main, args)
    assert result.exit_code == 1, result.output
    assert _said(result).strip().startswith(f"Error: {name}: {problem.format(n=surface.n_vertices)}")
    assert _said(result).count("\n") == 1
    assert _files(out) == [name]


def test_sweep_into_an_existing_file_is_refused(runner, scene_ply, tmp_path):
    target = tmp_path / "taken"
    target.write_text("mine")
    result = runner.invoke(main, ["sweep", str(scene_ply), "-o", str(target), "--no-plot"])
    _one_error_line(result, "taken", "exists and is not a directory; sweep writes a directory")
    assert target.read_text() == "mine"


def test_outputs_never_overwrite_inputs(runner, scene_ply, tmp_path):
    a, b = tmp_path / "a.ply", tmp_path / "b.ply"
    assert runner.invoke(main, _bake(scene_ply, a)).exit_code == 0
    assert runner.invoke(main, _bake(scene_ply, b, "--seed", "1")).exit_code == 0
    data = a.read_bytes()
    result = runner.invoke(main, ["compare", str(a), str(b), "--json", str(tmp_path / "." / "a.ply")])
    _one_error_line(result, "a.ply", "is also an input; refusing to write over it")
    assert a.read_bytes() == data
    source = scene_ply.read_bytes()
    result = runner.invoke(main, _bake(scene_ply, scene_ply))
    _one_error_line(result, scene_ply.name, "is also an input; refusing to write over it")
    assert scene_ply.read_bytes() == source


def test_field_bake_writes_usd(runner, scene_ply, tmp_path, field_npz):
    """--field with USD output records the fields as one string (customData takes no lists)."""
    from pxr import Usd

    outs = [tmp_path / "f.usda", tmp_path / "f.usdc", tmp_path / "f.ply"]
    args = _bake(scene_ply, outs[0], "--field", f"{field_npz}@0,0,2") + ["-o", str(outs[1]), "-o", str(outs[2])]
    result = runner.invoke(main, args)
    assert result.exit_code == 0, result.output
    assert np.array_equal(read_bake(outs[0]), read_bake(outs[2]).astype(np.float32))
    for out in outs[:2]:
        stage = Usd.Stage.Open(str(out))
        assert stage.GetPrimAtPath("/Root").GetCustomDataByKey("aobake")["fields"] == "box.npz"
    assert "comment aobake fields=box.npz" in outs[2].read_bytes()[:2000].decode("ascii", "replace")
