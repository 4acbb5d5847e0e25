"""The command line: exit codes, exact one-line errors, no partial outputs."""

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

from aobake.cli import main
from aobake.io import read_bake
from aobake.progress import COMPILING
from aobake.testing import scenes


@pytest.fixture
def scene_ply(tmp_path) -> Path:
    s, _ = scenes.sphere_on_ground(0.5, 2, gap=0.0, cells=6)
    path = tmp_path / "scene.ply"
    trimesh.Trimesh(s.positions, s.faces, process=False).export(path)
    return path


def _files(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir())


@pytest.mark.parametrize("suffix", [".ply", ".usda", ".usdc", ".usd"])
def test_bake_writes_each_format(runner, scene_ply, tmp_path, suffix):
    out = tmp_path / f"out{suffix}"
    result = runner.invoke(main, ["bake", str(scene_ply), "-o", str(out), "--rays", "16"])
    assert result.exit_code == 0, result.output
    ao = read_bake(out)
    n = len(trimesh.load(scene_ply, process=False).vertices)
    assert ao.shape == (n,)
    assert np.isfinite(ao).all() and ao.min() >= 0 and ao.max() <= 1
    assert "scene.ply:" in result.stderr and "M rays/s" in result.stderr
    # one summary line (after "compiling kernels ..." when this run compiled them)
    assert len([line for line in result.stderr.splitlines() if line != COMPILING]) == 1


def test_quiet_prints_nothing(runner, scene_ply, tmp_path):
    result = runner.invoke(
        main, ["bake", str(scene_ply), "-o", str(tmp_path / "o.ply"), "--rays", "8", "--quiet"]
    )
    assert result.exit_code == 0
    assert result.stderr == "" and result.stdout == ""


def test_same_seed_same_file_bytes(runner, scene_ply, tmp_path):
    outs = []
    for k, threads in enumerate(["1", "2"]):
        out = tmp_path / f"o{k}.usda"
        assert (
            runner.invoke(
                main,
                [
                    "bake",
                    str(scene_ply),
                    "-o",
                    str(out),
                    "--rays",
                    "16",
                    "--threads",
                    threads,
                    "-q",
                ],
            ).exit_code
            == 0
        )
        outs.append(out.read_bytes())
    assert outs[0] == outs[1]


def test_help_states_the_convention(runner):
    result = runner.invoke(main, ["--help"])
    assert result.exit_code == 0
    assert "1 - A" in result.output


def _write(path: Path, data: bytes | str) -> Path:
    path.write_bytes(data if isinstance(data, bytes) else data.encode())
    return path


ASCII_TRI = "ply\nformat ascii 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\nelement face {m}\nproperty list uchar int vertex_indices\nend_header\n"


def _ascii_ply(vertices, faces) -> str:
    text = ASCII_TRI.format(n=len(vertices), m=len(faces))
    text += "".join(" ".join(str(c) for c in v) + "\n" for v in vertices)
    text += "".join("3 " + " ".join(str(i) for i in f) + "\n" for f in faces)
    return text


BAD_INPUTS = {
    "missing": (lambda d: d / "missing.ply", "missing.ply: "),
    "directory": (lambda d: (d / "adir.ply").mkdir() or d / "adir.ply", "adir.ply: "),
    "garbage_ply": (lambda d: _write(d / "garbage.ply", os.urandom(256)), "garbage.ply: "),
    "garbage_obj": (lambda d: _write(d / "garbage.obj", b"\x00\xff" * 100), "garbage.obj: "),
    "truncated": (
        lambda d: _write(
            d / "trunc.ply", _ascii_ply([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])[:-12]
        ),
        "trunc.ply: ",
    ),
    "empty": (lambda d: _write(d / "empty.ply", _ascii_ply([], [])), "empty.ply: "),
    "no_faces": (
        lambda d: _write(d / "nofaces.ply", _ascii_ply([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [])),
        "nofaces.ply: ",
    ),
    "nan": (
        lambda d: _write(
            d / "nan.ply", _ascii_ply([[0, 0, 0], ["nan", 0, 0], [0, 1, 0]], [[0, 1, 2]])
        ),
        "nan.ply: ",
    ),
    "index": (
        lambda d: _write(
            d / "index.ply", _ascii_ply([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 7]])
        ),
        "index.ply: ",
    ),
    "suffix": (lambda d: _write(d / "mesh.xyz", "1 2 3\n"), "mesh.xyz: "),
}


@pytest.mark.parametrize("case", sorted(BAD_INPUTS))
def test_bad_input_is_one_line_error(runner, tmp_path, case):
    make, prefix = BAD_INPUTS[case]
    path = make(tmp_path)
    out = tmp_path / "out.ply"
    before = _files(tmp_path)
    result = runner.invoke(main, ["bake", str(path), "-o", str(out), "--rays", "4"])
    assert result.exit_code == 1, result.output
    assert result.stderr.startswith("Error: " + prefix), result.stderr
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr
    assert _files(tmp_path) == before


def test_unsupported_output_suffix_fails_before_loading(runner, tmp_path):
    # the input does not even exist: the suffix check comes first
    result = runner.invoke(
        main, ["bake", str(tmp_path / "nothing.ply"), "-o", str(tmp_path / "out.obj")]
    )
    assert result.exit_code == 1
    assert (
        result.stderr
        == "Error: out.obj: unsupported output suffix '.obj'; use one of .glb, .gltf, .ply, .usd, .usda, .usdc, .usdz\n"
    )


def test_missing_output_directory(runner, scene_ply, tmp_path):
    result = runner.invoke(main, ["bake", str(scene_ply), "-o", str(tmp_path / "no" / "out.ply")])
    assert result.exit_code == 1
    assert (
        result.stderr.startswith("Error: out.ply: output directory ")
        and "does not exist" in result.stderr
    )


def test_usage_errors_exit_2(runner, scene_ply, tmp_path):
    result = runner.invoke(
        main, ["bake", str(scene_ply), "-o", str(tmp_path / "o.ply"), "--rays", "0"]
    )
    assert result.exit_code == 2


def test_interrupt_leaves_no_output(tmp_path):
    # A bake big enough to be interrupted mid-trace; SIGINT -> exit != 0, no file, no traceback.
    s, _ = scenes.sphere_on_ground(0.5, 5, gap=0.0, cells=64)
    src = tmp_path / "big.ply"
    trimesh.Trimesh(s.positions, s.faces, process=False).export(src)
    out = tmp_path / "big_out.usdc"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "aobake",
            "bake",
            str(src),
            "-o",
            str(out),
            "--rays",
            "100000",
            "-q",
        ],
        stderr=subprocess.PIPE,
        text=True,
    )
    time.sleep(4.0)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode != 0
    assert "Traceback" not in err and err.strip().count("\n") == 0
    assert _files(tmp_path) == ["big.ply"]


@pytest.mark.parametrize("method", ["embree", "bunnell"])
def test_bake_options_come_from_the_method_options_class(runner, monkeypatch, scene_ply, tmp_path, method):
    """Every field of a method's options class is a `bake` flag whose help shows the
    class's default; a value set on the command line reaches the method's options, and
    the fields left unset keep the class's defaults."""
    import aobake.methods as methods
    from aobake.options import flag, specs

    cls = methods.options_class(method)
    text = " ".join(runner.invoke(main, ["bake", "--help"], terminal_width=1000).output.split())
    from aobake.cli import _shown

    for name, (spec, default) in specs(cls).items():
        assert flag(name, spec) in text, name
        if name not in ("seed", "threads"):
            assert f"{spec.help.rstrip('.')} [default: {_shown(spec, default)}]." in text, name
    seen = {}
    original = methods.run

    def spy(name, surface, options=None, progress=None, **changes):
        seen["options"] = methods.make_options(name, options, **changes)
        return original(name, surface, options, progress, **changes)

    monkeypatch.setattr(methods, "run", spy)
    given = {"embree": ["--rays", "8", "--max-distance", "0.5"], "bunnell": ["--theta", "3", "--max-distance", "0.5"]}
    out = tmp_path / "o.ply"
    result = runner.invoke(main, ["bake", str(scene_ply), "-o", str(out), "--method", method, "-q", *given[method]])
    assert result.exit_code == 0, result.output
    got = seen["options"]
    assert got.max_distance == 0.5
    assert (got.n_rays == 8) if method == "embree" else (got.theta == 3.0)
    untouched = {"embree": "tolerance", "bunnell": "passes"}[method]
    assert getattr(got, untouched) == getattr(cls(), untouched)


RUN_MAIN = """import atexit, sys, threading, time
class Late:
    def __del__(self):
        print("finalised", flush=True)
late = Late()
atexit.register(print, "atexit ran")
if sys.argv[1] == "thread":
    threading.Thread(target=lambda: (time.sleep(1.0), print("thread done"))).start()
sys.argv = ["aobake"] + sys.argv[2:]
from aobake.cli import main
main()
"""


def test_command_line_process_ends_without_finalisation(tmp_path, scene_ply):
    # `aobake ...` as a process ends by os._exit once the atexit functions ran and stdout
    # and stderr are flushed (Python's finalisation of numba's objects took ~0.3 s a bake):
    # outputs and exit codes as before, atexit functions run, finalisers do not; with a
    # thread still running, the usual exit, which waits for it
    script = tmp_path / "run.py"
    script.write_text(RUN_MAIN)

    def run(*args):
        proc = subprocess.run([sys.executable, str(script), *args], capture_output=True, text=True, timeout=300)
        return proc.returncode, proc.stdout.split("\n"), proc.stderr

    out = tmp_path / "out.ply"
    code, stdout, stderr = run("plain", "bake", str(scene_ply), "-o", str(out), "--rays", "4")
    assert code == 0 and out.exists() and stdout == ["atexit ran", ""], (stdout, stderr)
    assert stderr.startswith("scene.ply: ") and stderr.endswith(f"-> {out}\n")
    code, stdout, stderr = run("plain", "bake", str(tmp_path / "none.ply"), "-o", str(out))
    assert code == 1 and stdout == ["atexit ran", ""] and stderr == "Error: none.ply: file not found\n"
    code, stdout, _ = run("plain", "--version")
    assert code == 0 and stdout[0].endswith("version 0.1.0") and stdout[1:] == ["atexit ran", ""]
    code, stdout, _ = run("thread", "--version")
    assert code == 0 and stdout[1:] == ["thread done", "atexit ran", "finalised", ""], stdout
