"""The bad-input suite for every command: one line naming the problem, exit code 1, no
traceback, no output left behind."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

from aobake.cli import main
from aobake.testing import scenes

ASCII_HEADER = (
    "ply\nformat ascii 1.0\nelement vertex {n}\nproperty float x\nproperty float y\n"
    "property float z\nelement face {m}\nproperty list uchar int vertex_indices\nend_header\n"
)


def _ascii_ply(vertices, faces) -> str:
    text = ASCII_HEADER.format(n=len(vertices), m=len(faces))
    text += "".join(" ".join(str(c) for c in v) + "\n" for v in vertices)
    text += "".join("3 " + " ".join(str(i) for i in f) + "\n" for f in faces)
    return text


TRI = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]

BAD_MESHES = {
    "missing": lambda d: d / "missing.ply",
    "directory": lambda d: (d / "adir.ply").mkdir() or d / "adir.ply",
    "garbage": lambda d: _write(d / "garbage.ply", os.urandom(300)),
    "truncated": lambda d: _write(d / "trunc.ply", _ascii_ply(TRI, [[0, 1, 2]])[:-12]),
    "empty": lambda d: _write(d / "empty.ply", _ascii_ply([], [])),
    "nan": lambda d: _write(d / "nan.ply", _ascii_ply([[0, 0, 0], ["nan", 0, 0], [0, 1, 0]], [[0, 1, 2]])),
    "index": lambda d: _write(d / "index.ply", _ascii_ply(TRI, [[0, 1, 7]])),
}


def _write(path: Path, data) -> Path:
    path.write_bytes(data if isinstance(data, bytes) else data.encode())
    return path


def _good_mesh(d: Path) -> Path:
    s, _ = scenes.sphere_on_ground(0.5, 1, cells=2)
    path = d / "good.ply"
    trimesh.Trimesh(s.positions, s.faces, process=False).export(path)
    return path


# command -> (arguments for an input path and an output in directory d)
COMMANDS = {
    "bake": lambda src, d: ["bake", str(src), "-o", str(d / "out.ply"), "--rays", "4"],
    "field": lambda src, d: ["field", str(src), "-o", str(d / "out.npz"), "--resolution", "2", "--radial-samples", "3", "--raster-size", "4"],
    "preview": lambda src, d: ["preview", str(src), "-o", str(d / "out.png"), "--size", "16"],
    "compare": lambda src, d: ["compare", str(src), str(src), "--json", str(d / "out.json")],
    "sweep": lambda src, d: ["sweep", str(src), "-o", str(d / "sweep"), "--reference-rays", "16", "--no-plot"],
}


def _assert_one_line_error(result, prefix: str):
    assert result.exit_code == 1, result.output
    assert result.stderr.startswith("Error: " + prefix), result.stderr
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr


@pytest.mark.parametrize("command", sorted(COMMANDS))
@pytest.mark.parametrize("case", sorted(BAD_MESHES))
def test_bad_mesh_for_every_command(tmp_path, command, case):
    src = BAD_MESHES[case](tmp_path)
    before = sorted(p.name for p in tmp_path.iterdir())
    result = CliRunner().invoke(main, COMMANDS[command](src, tmp_path))
    _assert_one_line_error(result, src.name + ": ")
    assert sorted(p.name for p in tmp_path.iterdir()) == before


@pytest.mark.parametrize(
    "args,message",
    [
        (lambda g, d: ["bake", str(g), "-o", str(d / "o.obj")], "o.obj: unsupported output suffix"),
        (lambda g, d: ["preview", str(g), "-o", str(d / "o.jpg")], "o.jpg: previews are written as PNG"),
        (lambda g, d: ["compare", str(g), str(g), "--plot", str(d / "o.svg")], "o.svg: images are written as PNG"),
        (lambda g, d: ["bake", str(g), "-o", str(d / "nodir" / "o.ply")], "o.ply: output directory"),
        (lambda g, d: ["field", str(g), "-o", str(d / "nodir" / "f.npz")], "f.npz: output directory"),
        (lambda g, d: ["preview", str(g), "-o", str(d / "nodir" / "o.png")], "o.png: output directory"),
        (lambda g, d: ["compare", str(g), str(g), "--json", str(d / "nodir" / "o.json")], "o.json: output directory"),
    ],
)
def test_bad_outputs(tmp_path, args, message):
    good = _good_mesh(tmp_path)
    result = CliRunner().invoke(main, args(good, tmp_path))
    _assert_one_line_error(result, message)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["good.ply"]


def test_bad_field_file_for_bake(tmp_path):
    good = _good_mesh(tmp_path)
    bad = _write(tmp_path / "f.npz", b"PK\x03\x04 not really a zip")
    result = CliRunner().invoke(main, ["bake", str(good), "-o", str(tmp_path / "o.ply"), "--field", str(bad)])
    _assert_one_line_error(result, "f.npz: ")
    assert not (tmp_path / "o.ply").exists()


@pytest.mark.parametrize(
    "command",
    [
        ["bake", "{src}", "-o", "{out}.usdc", "--rays", "100000", "-q"],
        ["field", "{src}", "-o", "{out}.npz", "--resolution", "64", "--sampler", "embree", "--rays", "100000", "-q"],
        ["sweep", "{src}", "-o", "{out}_dir", "--reference-rays", "100000", "-q", "--no-plot"],
    ],
    ids=["bake", "field", "sweep"],
)
def test_interrupt_leaves_no_output(tmp_path, command):
    s, _ = scenes.sphere_on_ground(0.5, 4, gap=0.0, cells=32)
    src = tmp_path / "big.ply"
    trimesh.Trimesh(s.positions, s.faces, process=False).export(src)
    out = tmp_path / "result"
    args = [a.format(src=src, out=out) for a in command]
    proc = subprocess.Popen([sys.executable, "-m", "aobake", *args], stderr=subprocess.PIPE, text=True)
    time.sleep(4.0)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode != 0
    assert "Traceback" not in err and err.strip().count("\n") == 0
    leftovers = sorted(p.name for p in tmp_path.rglob("*") if p.is_file())
    assert leftovers == ["big.ply"]


def test_swallowed_interrupt_is_raised_again_at_the_next_advance():
    """Python drops a KeyboardInterrupt raised inside a C callback (numba's compiler is
    one): the CLI's handler remembers Ctrl-C, and the next progress step raises it."""
    from aobake import progress as P

    try:
        P.install_interrupt_handler()
        assert signal.getsignal(signal.SIGINT) is P._on_sigint
        P.NullProgress().advance(1)  # nothing pending
        try:
            P._on_sigint(signal.SIGINT, None)
        except KeyboardInterrupt:
            pass  # dropped, as "Exception ignored on calling ctypes callback" drops it
        with open(os.devnull, "w") as sink:
            for progress in (P.NullProgress(), P.StderrProgress(stream=sink)):
                with pytest.raises(KeyboardInterrupt):
                    progress.advance(1)
        P.install_interrupt_handler()  # a new command starts clean
        P.NullProgress().advance(1)

        class Dropped:  # what Python hands sys.unraisablehook
            exc_value = KeyboardInterrupt()

        seen = []
        P._previous_hook = seen.append
        sys.unraisablehook(Dropped)  # silent: remembered by the handler instead
        other = type("Other", (), {"exc_value": ValueError("x")})
        sys.unraisablehook(other)
        assert seen == [other]  # anything else still reaches the previous hook
    finally:
        P._previous_hook = sys.__unraisablehook__
        sys.unraisablehook = sys.__unraisablehook__
        signal.signal(signal.SIGINT, signal.default_int_handler)
        P._interrupted = False


def test_failure_after_a_dropped_interrupt_is_an_abort(tmp_path, monkeypatch):
    """numba, interrupted inside its compiler's callback, can fail later in its own way
    ("no compiled object yet"): after a Ctrl-C that is an abort (exit 1, one line), and
    without one the error is not hidden."""
    import aobake.pipeline
    from aobake import progress as P

    src = tmp_path / "m.ply"
    trimesh.creation.icosphere(subdivisions=1).export(src)

    def broken(*args, **kwargs):
        if dropped:
            P._interrupted = True  # what the handler records before Python drops the raise
        raise RuntimeError("no compiled object yet")

    monkeypatch.setattr(aobake.pipeline, "bake_file", broken)
    try:
        dropped = True
        result = CliRunner().invoke(main, ["bake", str(src), "-o", str(tmp_path / "o.ply")])
        assert result.exit_code == 1
        assert result.output.strip() == "Aborted!"
        assert not (tmp_path / "o.ply").exists()
        dropped = False
        result = CliRunner().invoke(main, ["bake", str(src), "-o", str(tmp_path / "o.ply")])
        assert isinstance(result.exception, RuntimeError)
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)
        sys.unraisablehook = sys.__unraisablehook__
        P._interrupted = False


def test_compare_refuses_npy_of_wrong_shape(tmp_path):
    np.save(tmp_path / "a.npy", np.zeros((3, 2)))
    result = CliRunner().invoke(main, ["compare", str(tmp_path / "a.npy"), str(tmp_path / "a.npy")])
    _assert_one_line_error(result, "a.npy: ")
