"""Results do not depend on numba's cache: a kernel compiled in this process and the same
kernel loaded from the cache give the same bits (issue 19, docs/first-run.md)."""

from __future__ import annotations

import importlib
import pkgutil
import sys
from pathlib import Path

import pytest
from numba.core.registry import CPUDispatcher

import aobake.kernels

BENCH = Path(__file__).resolve().parents[1] / "bench"

# the only kernels allowed fastmath: the tree pass and its vectorised list sums, and the
# light transfer's tree gather with its list sums (inlined into it alone; same bits compiled
# or loaded from the cache, checked in fresh interpreters)
FASTMATH_KERNELS = {
    "transfertree.gather_tree",
    "transfertree.near_sums",
    "transfertree.far_sums",
    "treepass.thread_share",
    "treepass.thread_share_unbinned",
    "treepass.hierarchy_pass_inlined",
    "listsums.direction_sums",
    "listsums.direction_sums_flat",
    "listsums.far_sums_flat",
    "listsums.near_disk_sums_flat",
    "listsums.binned_sums_flat",
}


def test_only_the_tree_passes_use_fastmath():
    """fastmath lets LLVM round a kernel's copy in a caller unlike the kernel itself."""
    with_fastmath = set()
    for info in pkgutil.iter_modules(aobake.kernels.__path__):
        module = importlib.import_module(f"aobake.kernels.{info.name}")
        for name, obj in vars(module).items():
            if isinstance(obj, CPUDispatcher) and obj.__module__ == module.__name__:
                if obj.targetoptions.get("fastmath"):
                    with_fastmath.add(f"{info.name}.{name}")
    assert with_fastmath == FASTMATH_KERNELS


@pytest.mark.slow
def test_field_fit_same_bits_compiled_or_cached(tmp_path):
    """A field fit in fresh interpreters: compiling into an empty cache, loading from
    it, and compiling after another fit filled the cache (bench/cache_states.py; about
    55 s of CPU, nearly all compiling, twice, in one thread). The disk method's case
    compiles for minutes and its passes >= 2 still differ: bench only."""
    sys.path.insert(0, str(BENCH))
    try:
        import cache_states
    finally:
        sys.path.remove(str(BENCH))
    results = cache_states.run_states(["field"], 2, str(tmp_path))
    assert len(results) == 3
    assert cache_states.differences(results) == []
