"""Shared fixtures and hypothesis profiles."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner
from hypothesis import settings

settings.register_profile("ci", deadline=None, derandomize=True, print_blob=True)
settings.register_profile("dev", deadline=None)
settings.load_profile("ci" if os.environ.get("CI") else "dev")


@pytest.fixture(scope="session", autouse=True)
def _compile_ahead():
    """With a cold numba cache (a fresh clone's CI), ``aobake warm-up`` compiles the
    commands' kernels in a background process on the other core while the suite runs
    (numba compiles on one thread); the tests then load from the cache what it has
    compiled, or compile it themselves if they get there first. No result depends on it."""
    from aobake import precompile

    proc = None
    if (os.cpu_count() or 1) >= 2 and precompile.is_cached("tree-pass") is False:
        root = str(Path(__file__).resolve().parent.parent)
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH")) if p)}
        proc = subprocess.Popen([sys.executable, "-m", "aobake", "warm-up"], stdin=subprocess.DEVNULL,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)  # fmt: skip
    yield
    if proc is not None and proc.poll() is None:
        proc.kill()
        proc.wait()


@pytest.fixture
def runner() -> CliRunner:
    """A click runner for the CLI (stdout and stderr kept apart)."""
    return CliRunner()


@pytest.fixture
def scene_ply(tmp_path) -> Path:
    """A small sphere resting on a floor (contacts, a crevice, open ground) as PLY;
    modules that need a larger scene define their own."""
    import trimesh

    from aobake.testing import scenes

    s, _ = scenes.sphere_on_ground(0.5, 1, gap=0.0, cells=3)
    path = tmp_path / "scene.ply"
    trimesh.Trimesh(s.positions, s.faces, process=False).export(path)
    return path
