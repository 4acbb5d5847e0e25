"""Compiling on both cores (aobake.precompile): a helper process compiles a kernel into
numba's cache while the command goes on; the command waits for it, or compiles itself
when the helper fails or is too slow. Stub helpers keep these tests cheap."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numba
import pytest

from aobake import precompile
from aobake.progress import COMPILING, CompileWatch

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture
def helpers():
    """Helpers enabled for the test; any left running are ended after it."""
    with precompile.enabled():
        yield precompile
    assert not precompile._helpers


def _python(code: str) -> list[str]:
    return [sys.executable, "-c", code]


def test_none_when_disabled_or_on_one_thread(helpers):
    assert not helpers.start("stub", threads=1, command=_python("pass"))  # --threads 1: one core
    helpers.enable(False)
    assert not helpers.start("stub", command=_python("pass"))
    assert "stub" not in helpers._helpers
    assert not helpers.wait("stub")  # nothing to wait for: returns at once


def test_a_failing_helper_costs_only_its_time(helpers):
    assert helpers.start("stub", command=_python("raise SystemExit(1)"))
    proc = helpers._helpers["stub"]
    t0 = time.perf_counter()
    assert not helpers.wait("stub")  # the caller compiles itself
    assert time.perf_counter() - t0 < 10.0
    assert proc.returncode == 1 and "stub" not in helpers._helpers


def test_a_slow_helper_is_killed_after_the_limit_and_counted_as_compiling(helpers):
    assert helpers.start("stub", command=_python("import time; time.sleep(60)"))
    proc = helpers._helpers["stub"]
    with CompileWatch() as watch:
        t0 = time.perf_counter()
        assert not helpers.wait("stub", limit=0.3)
        waited = time.perf_counter() - t0
    assert 0.3 <= waited < 10.0
    assert proc.returncode is not None and proc.returncode != 0  # killed and reaped
    assert watch.count == 1 and 0.3 <= watch.seconds <= waited


def test_helper_ends_when_the_command_does(helpers):
    """The helper reads its stdin, the command's pipe: closed (the command ended, even by
    SIGKILL), it exits at once; stop_all (atexit) kills and reaps the rest."""
    code = (
        "from aobake.precompile import _watch_parent; _watch_parent(); import time; time.sleep(60)"
    )
    assert helpers.start("a", command=_python(code))
    assert helpers.start("b", command=_python(code))
    a, b = helpers._helpers["a"], helpers._helpers["b"]
    a.stdin.close()
    assert a.wait(timeout=30) == 3
    helpers.stop_all()
    assert b.returncode is not None and not helpers._helpers


class _Seen(Exception):
    pass


def _first_call_types(monkeypatch, module, name, work) -> tuple:
    """numba's types of the first call of ``module.name`` in ``work()`` (not run)."""
    calls = []

    def record(*args):
        calls.append(tuple(numba.typeof(a) for a in args))
        raise _Seen

    monkeypatch.setattr(module, name, record)
    with pytest.raises(_Seen):
        work()
    monkeypatch.undo()
    return calls[0]


def test_examples_have_the_types_the_commands_pass(monkeypatch):
    """Each helper compiles its kernel for its target's example arguments: the types of
    the command's call (else the command would compile the kernel again)."""
    from aobake.kernels import field_fit, treepass
    from aobake.mesh import surface_from_arrays
    from aobake.methods import run
    from aobake.methods.fields import fit_field
    from aobake.pipeline import warm_up_scene

    scene = surface_from_arrays(*warm_up_scene())
    for target, module, name, work in [
        ("tree-pass", treepass, "thin_pass_unbinned", lambda: run("bunnell", scene, {}, None)),
        (
            "field-fit",
            field_fit,
            "fit_texels",
            lambda: fit_field(scene, resolution=4, radial_samples=8),
        ),
    ]:
        kernel, sig = precompile.kernel_signature(target)
        assert kernel is getattr(module, name)
        assert _first_call_types(monkeypatch, module, name, work) == sig, target


def test_command_loads_what_the_helper_compiled(tmp_path):
    """End to end on a small kernel, in a fresh process and an empty cache: the helper
    compiles it, the command waits (one compile event, its wait), then loads it from the
    cache instead of compiling (numba's cache hits)."""
    (tmp_path / "small_target.py").write_text(
        textwrap.dedent("""
        import numpy as np

        from aobake.kernels.polygon import vertex_areas


        def target():
            return vertex_areas, (np.zeros((3, 3)), np.zeros((1, 3), dtype=np.int64), np.zeros(3))
    """)
    )
    script = textwrap.dedent("""
        import sys
        from aobake import precompile
        from aobake.progress import CompileWatch
        import small_target

        precompile.TARGETS["small"] = "small_target:target"
        precompile.enable()
        before = precompile.is_cached("small")
        helper = "import aobake.precompile as p; p.TARGETS['small'] = 'small_target:target'; p.main(['small'])"
        assert precompile.start("small", command=[sys.executable, "-c", helper])
        with CompileWatch(sys.stdout) as watch:
            done = precompile.wait("small")
            kernel, args = small_target.target()
            kernel(*args)
        print(before, done, watch.count, precompile.is_cached("small"), sum(kernel.stats.cache_hits.values()))
    """)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"),
               PYTHONPATH=os.pathsep.join([str(ROOT), str(tmp_path)]))  # fmt: skip
    out = subprocess.run(
        [sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.split("\n")[:2] == [COMPILING, "False True 1 True 1"]
