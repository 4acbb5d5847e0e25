"""`aobake batch`: outputs equal `aobake bake`, the manifest, reruns, failures, workers
killed, an external scheduler, --split, Ctrl-C and the OUTDIR lock.

Small meshes and few rays: the cost is the clusters' start-up (one shared LocalCluster
of 2 worker processes for the Python-API tests).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

from aobake import batch
from aobake.cli import main
from aobake.io import read_bake
from aobake.pipeline import bake_file, bake_part, write_parts
from aobake.progress import BatchBar
from aobake.testing import scenes

DATA = Path(__file__).resolve().parents[1] / "data"
REPO = Path(__file__).resolve().parents[1]
RAYS = ["--rays", "16"]


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    return env


@pytest.fixture(scope="module")
def client():
    from distributed import Client, LocalCluster

    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address="127.0.0.1:0", silence_logs=50)
    c = Client(cluster)
    yield c
    c.close()
    cluster.close()


@pytest.fixture
def library(tmp_path) -> Path:
    """The bundled meshes, one in a subdirectory, and a broken file."""
    lib = tmp_path / "lib"
    (lib / "sub").mkdir(parents=True)
    shutil.copy(DATA / "bunny.ply", lib / "bunny.ply")
    shutil.copy(DATA / "box_stack.ply", lib / "sub" / "box_stack.ply")
    s, _ = scenes.sphere_on_ground(0.5, 2, gap=0.0, cells=6)
    trimesh.Trimesh(s.positions, s.faces, process=False).export(lib / "scene.obj")
    (lib / "broken.ply").write_text("ply\nformat ascii 1.0\nelement vertex 3\nend_header\n0 0\n")
    return lib


def _reference(tmp_path: Path, source: Path, suffix: str, *options: str) -> bytes:
    """What `aobake bake` writes for ``source`` with the same options."""
    out = tmp_path / "ref" / f"{source.stem}{suffix}"
    out.parent.mkdir(exist_ok=True)
    result = CliRunner().invoke(main, ["bake", str(source), "-o", str(out), "-q", *options])
    assert result.exit_code == 0, result.output
    return out.read_bytes()


def _hidden(directory: Path) -> list[str]:
    """Hidden files (temporaries) other than the lock."""
    return sorted(p.name for p in directory.rglob(".*") if p.name != batch.LOCK)


def test_cli_local_cluster_bakes_a_library_and_a_rerun_retries_only_the_failure(library, tmp_path):
    out = tmp_path / "out"
    runner = CliRunner()
    args = ["batch", str(library), "-o", str(out), "--workers", "2", *RAYS, "--to", "ply,usda"]
    result = runner.invoke(main, args)
    assert result.exit_code == 1, result.output
    assert "batch: 4 inputs: 3 baked, 0 up to date, 1 failed" in result.stderr
    assert "failed: broken.ply: " in result.stderr
    for rel in ("bunny.ply", "sub/box_stack.ply", "scene.obj"):
        src = library / rel
        for suffix in (".ply", ".usda"):
            got = (out / rel).with_suffix(suffix).read_bytes()
            assert got == _reference(tmp_path, src, suffix, *RAYS), (rel, suffix)
    manifest = json.loads((out / "manifest.json").read_text())
    records = {r["input"]: r for r in manifest["inputs"]}
    assert records["broken.ply"]["status"] == "failed"
    assert records["broken.ply"]["error"].startswith("broken.ply: ")
    bunny = records["bunny.ply"]
    assert bunny["status"] == "done" and bunny["vertices"] == 1839 and bunny["rays"] == 1839 * 16
    assert bunny["worker"].startswith("tcp://") and bunny["method"] == "embree" and bunny["seconds"] > 0
    assert bunny["output_hashes"] == {n: batch.file_hash(out / n) for n in ("bunny.ply", "bunny.usda")}
    csv_lines = (out / "manifest.csv").read_text().splitlines()
    assert csv_lines[0].startswith("input,status,error,vertices") and len(csv_lines) == 5
    assert not (out / "broken.ply").exists() and _hidden(out) == []

    mtimes = {p: p.stat().st_mtime_ns for p in out.rglob("*.usda")}
    args[args.index("--workers") + 1] = "1"  # starts sooner
    result = runner.invoke(main, args)  # everything up to date; the broken one tried again
    assert result.exit_code == 1
    assert "batch: 4 inputs: 0 baked, 3 up to date, 1 failed" in result.stderr
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*.usda")} == mtimes

    shutil.copy(DATA / "sphere_on_ground.ply", library / "broken.ply")  # fixed
    result = runner.invoke(main, args)
    assert result.exit_code == 0, result.output
    assert "batch: 4 inputs: 1 baked, 3 up to date in" in result.stderr
    assert (out / "broken.ply").read_bytes() == _reference(tmp_path, library / "broken.ply", ".ply", *RAYS)


def test_changed_input_options_or_outputs_are_baked_again(client, library, tmp_path):
    (library / "broken.ply").unlink()
    out = tmp_path / "out"
    s16 = batch.Settings(options={"n_rays": 16})
    assert batch.run_batch([library], out, settings=s16, client=client).done == 3
    again = batch.run_batch([library], out, settings=s16, client=client)
    assert (again.done, again.skipped) == (0, 3)
    # the default of an option, given or not, is the same setting
    assert batch.run_batch([library], out, settings=batch.Settings(options={"n_rays": 16, "seed": 0}), client=client).skipped == 3
    (out / "bunny.usda").write_text("#usda 1.0\n")  # an output changed by hand
    shutil.copy(DATA / "sphere_on_ground.ply", library / "scene.obj".replace("obj", "ply"))
    (library / "scene.obj").unlink()
    r = batch.run_batch([library], out, settings=s16, client=client)
    assert {x["input"]: x["status"] for x in r.records} == {
        "bunny.ply": "done", "scene.ply": "done", "sub/box_stack.ply": "skipped"
    }  # fmt: skip
    assert batch.run_batch([library], out, settings=batch.Settings(options={"n_rays": 8}), client=client).done == 3
    assert batch.run_batch([library], out, settings=batch.Settings(options={"n_rays": 8}), client=client, force=True).done == 3


def test_split_equals_the_unsplit_bake(client, tmp_path):
    src = tmp_path / "in" / "scene.ply"
    src.parent.mkdir()
    shutil.copy(DATA / "sphere_on_ground.ply", src)
    # the options as the CLI passes them (the PLY header lists them in this order)
    cases = (({"n_rays": 16}, RAYS), ({"n_rays": 64, "tolerance": 0.05}, ["--rays", "64", "--tolerance", "0.05"]))
    for options, flags in cases:
        out = tmp_path / f"out{len(flags)}"
        r = batch.run_batch([src], out, formats=("ply", "usdc"), settings=batch.Settings(options=options), client=client, split=3)
        assert r.done == 1 and r.failed == 0
        for suffix in (".ply", ".usdc"):
            assert (out / f"scene{suffix}").read_bytes() == _reference(tmp_path, src, suffix, *flags)
        assert r.records[0]["rays"] == read_rays(src, options)


def read_rays(src, options) -> int:
    from aobake.methods import run
    from aobake.pipeline import as_surface

    return run("embree", as_surface(src), options).n_rays


def test_parts_stitch_to_the_whole_bake_without_dask(tmp_path):
    src = DATA / "box_stack.ply"
    whole = bake_part(src, n_rays=16)
    pieces = [bake_part(src, parts=(k, 4), n_rays=16) for k in range(4)]
    assert [p.vertices for p in pieces][0] == (0, 162) and pieces[-1].vertices[1] == 651
    np.testing.assert_array_equal(np.concatenate([p.ao for p in pieces]), whole.ao)
    assert sum(p.n_rays for p in pieces) == whole.n_rays
    write_parts(src, tmp_path / "a.ply", pieces, n_rays=16)
    bake_file(src, tmp_path / "b.ply", n_rays=16)
    assert (tmp_path / "a.ply").read_bytes() == (tmp_path / "b.ply").read_bytes()
    with pytest.raises(ValueError, match="cover"):
        write_parts(src, tmp_path / "c.ply", pieces[:3], n_rays=16)
    with pytest.raises(ValueError, match="couples all vertices"):
        bake_part(src, method="bunnell", parts=(0, 2))


def test_a_killed_worker_does_not_stop_the_batch_nor_leave_partial_files(client, tmp_path):
    lib = tmp_path / "lib"
    lib.mkdir()
    for k in range(6):
        shutil.copy(DATA / "bunny.ply", lib / f"bunny{k}.ply")
    out = tmp_path / "out"
    killed = {}

    def kill_a_busy_worker():
        deadline = time.time() + 30
        while time.time() < deadline and not killed:
            busy = [w for w, tasks in client.processing().items() if any("bake_task" in t for t in tasks)]
            if busy:
                pid = client.run(os.getpid, workers=[busy[0]])[busy[0]]
                time.sleep(0.05)
                os.kill(pid, signal.SIGKILL)
                killed["pid"] = pid
            time.sleep(0.02)

    killer = threading.Thread(target=kill_a_busy_worker)
    killer.start()
    r = batch.run_batch([lib], out, formats=("ply",), settings=batch.Settings(options={"n_rays": 2048}), client=client)
    killer.join()
    assert killed, "no worker was busy"
    assert (r.done, r.failed) == (6, 0)
    assert _hidden(out) == []
    expected = read_bake(out / "bunny0.ply")
    for k in range(1, 6):
        np.testing.assert_array_equal(read_bake(out / f"bunny{k}.ply"), expected)


def test_stale_temporaries_of_our_outputs_are_removed(tmp_path):
    job = batch.Job("a.ply", str(tmp_path / "a.ply"), (str(tmp_path / "o" / "a.ply"), str(tmp_path / "o" / "a.usda")))
    (tmp_path / "o").mkdir()
    stale = tmp_path / "o" / ".a.k2j_x9q0.usda"  # what atomic_write names its temporaries
    keep = [tmp_path / "o" / ".a.notes.usda", tmp_path / "o" / ".b.k2j_x9q0.usda", tmp_path / "o" / "a.usda"]
    for p in [stale, *keep]:
        p.write_text("x")
    assert batch.remove_stale_temporaries([job]) == 1
    assert not stale.exists() and all(p.exists() for p in keep)


def test_scheduler_option_uses_a_running_dask_cluster(library, tmp_path):
    (library / "broken.ply").unlink()
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    address = f"tcp://127.0.0.1:{port}"
    dask = str(Path(sys.executable).parent / "dask")
    quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL, "env": _env()}
    scheduler = subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"], **quiet)
    worker = subprocess.Popen([dask, "worker", address, "--nthreads", "1", "--no-dashboard", "--host", "127.0.0.1"], **quiet)
    try:
        out = tmp_path / "out"
        args = ["batch", str(library), "-o", str(out), "--scheduler", address, *RAYS, "--to", "ply"]
        done = CliRunner().invoke(main, args)
        assert done.exit_code == 0, done.output
        assert "3 baked" in done.stderr
        for rel in ("bunny.ply", "sub/box_stack.ply", "scene.obj"):
            assert (out / rel).with_suffix(".ply").read_bytes() == _reference(tmp_path, library / rel, ".ply", *RAYS)
        workers = {r["worker"] for r in json.loads((out / "manifest.json").read_text())["inputs"]}
        assert len(workers) == 1 and workers.pop().startswith("tcp://127.0.0.1:")
    finally:
        for p in (worker, scheduler):
            p.terminate()
        for p in (worker, scheduler):
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()


def test_ctrl_c_cancels_cleanly_and_a_rerun_resumes(tmp_path):
    lib = tmp_path / "lib"
    lib.mkdir()
    for k in range(6):
        shutil.copy(DATA / "bunny.ply", lib / f"b{k}.ply")
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "aobake", "batch", str(lib), "-o", str(out), "--workers", "2", "--rays", "1024", "--to", "ply"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env(), start_new_session=True)
    deadline = time.time() + 60
    while time.time() < deadline and not list(out.glob("b*.ply")):
        time.sleep(0.05)
    time.sleep(0.3)  # the first result reaches the client
    os.killpg(proc.pid, signal.SIGINT)  # what a terminal's Ctrl-C does: the whole group
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "batch interrupted: " in err
    assert "Traceback" not in err
    assert _hidden(out) == []
    records = {r["input"]: r for r in json.loads((out / "manifest.json").read_text())["inputs"]}
    baked = {k for k, r in records.items() if r["status"] == "done"}
    assert 1 <= len(baked) < 6
    expected = read_bake(out / sorted(baked)[0])
    for p in out.glob("b*.ply"):  # every file there is whole
        np.testing.assert_array_equal(read_bake(p), expected)
    again = subprocess.run(cmd, capture_output=True, text=True, env=_env(), timeout=120)
    assert again.returncode == 0, again.stderr
    assert f"{6 - len(baked)} baked, {len(baked)} up to date" in again.stderr


def test_a_second_batch_on_the_same_outdir_is_refused(library, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    with batch.outdir_lock(out):
        result = CliRunner().invoke(main, ["batch", str(library / "bunny.ply"), "-o", str(out), *RAYS])
    assert result.exit_code == 1
    assert result.stderr.strip() == f"Error: {out}: another aobake batch (pid {os.getpid()}) is writing here; wait for it to end"
    assert sorted(p.name for p in out.iterdir()) == [batch.LOCK]


def test_names_that_collide_are_refused_before_any_work(library, tmp_path):
    shutil.copy(DATA / "bunny.ply", library / "scene.ply")  # scene.obj and scene.ply -> out/scene.*
    out = tmp_path / "out"
    result = CliRunner().invoke(main, ["batch", str(library), "-o", str(out), *RAYS])
    assert result.exit_code == 1
    assert result.stderr.startswith("Error: scene.ply: both ") and result.stderr.count("\n") == 1
    assert not out.exists()
    result = CliRunner().invoke(main, ["batch", str(library / "bunny.ply"), "-o", str(library), "--to", "ply"])
    assert result.exit_code == 1 and "would overwrite an input" in result.stderr


def test_bunnell_split_is_refused_in_one_line(library, tmp_path):
    result = CliRunner().invoke(main, ["batch", str(library), "-o", str(tmp_path / "o"), "--method", "bunnell", "--split", "2"])
    assert result.exit_code == 2
    assert "Error: --split applies to --method embree only: bunnell couples all vertices" in result.output
    assert not (tmp_path / "o").exists()


def test_inputs_from_lists_patterns_and_directories(library, tmp_path):
    listing = tmp_path / "list.txt"
    listing.write_text("# meshes\nlib/bunny.ply\n\nlib/sub\n")
    found = batch.find_inputs([listing, str(library / "*.obj")])
    assert [(src.name, rel.as_posix()) for src, rel in found] == [
        ("bunny.ply", "bunny.ply"), ("box_stack.ply", "box_stack.ply"), ("scene.obj", "scene.obj")
    ]  # fmt: skip
    for bad, message in ((tmp_path / "nope.ply", "file not found"), (str(tmp_path / "*.stl"), "no file matches")):
        result = CliRunner().invoke(main, ["batch", str(bad), "-o", str(tmp_path / "o")])
        assert result.exit_code == 1 and message in result.stderr and result.stderr.count("\n") == 1


def test_emit_commands_print_what_batch_would_bake(library, tmp_path):
    (library / "broken.ply").unlink()
    out = tmp_path / "out"
    result = CliRunner().invoke(main, ["batch", str(library), "-o", str(out), "--emit-commands", *RAYS, "--color", "--to", "ply"])
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    assert len(lines) == 3 and all(line.startswith("aobake bake ") for line in lines)
    import shlex

    for line in lines:  # each line runs as it is and writes what `aobake bake` writes
        args = shlex.split(line)[1:]
        assert CliRunner().invoke(main, [*args, "-q"]).exit_code == 0
    src = library / "sub" / "box_stack.ply"
    assert (out / "sub" / "box_stack.ply").read_bytes() == _reference(tmp_path, src, ".ply", *RAYS, "--color")


def test_batch_bar_counts_and_eta():
    import io

    stream = io.StringIO()
    bar = BatchBar(stream, width=10)
    bar.start(10)
    bar.t0 -= 4.0  # 4 s in
    bar.update(done=3, failed=1, skipped=2)
    text = bar.text()
    assert "6/10: 3 done, 1 failed, 2 skipped" in text
    eta = float(text.split("eta")[1].strip().rstrip("s"))
    assert eta == pytest.approx(4.0 * 4 / 4, abs=0.1)  # 4 left at 4 baked per 4 s
    assert "[######----]" in text


def test_retries_rerun_unexpected_failures_but_not_bad_meshes(library, tmp_path, monkeypatch):
    from distributed import Client, LocalCluster

    import aobake.pipeline

    calls = []
    real = aobake.pipeline.bake_file

    def flaky(source, *args, **kwargs):  # the first try of every input runs out of memory
        calls.append(Path(source).name)
        if calls.count(Path(source).name) == 1:
            raise MemoryError("cannot allocate 4 GB")
        return real(source, *args, **kwargs)

    monkeypatch.setattr(aobake.pipeline, "bake_file", flaky)
    (library / "sub" / "box_stack.ply").unlink()
    (library / "scene.obj").unlink()  # bunny.ply and broken.ply left
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address="127.0.0.1:0") as cluster:
        with Client(cluster) as client:  # in this process: the tasks see the patch
            s16 = batch.Settings(options={"n_rays": 16})
            r = batch.run_batch([library], tmp_path / "a", settings=s16, client=client, retries=0)
            assert {x["input"]: x["error"] for x in r.records} == {
                "bunny.ply": "MemoryError: cannot allocate 4 GB",
                "broken.ply": "MemoryError: cannot allocate 4 GB",
            }
            calls.clear()
            r = batch.run_batch([library], tmp_path / "b", settings=s16, client=client, retries=1)
    status = {x["input"]: x["status"] for x in r.records}
    assert status == {"bunny.ply": "done", "broken.ply": "failed"}
    assert sorted(calls) == ["broken.ply", "broken.ply", "bunny.ply", "bunny.ply"]  # retried once each
    assert r.records[0]["error"].startswith("broken.ply: ")  # the mesh's own error, not retried again
