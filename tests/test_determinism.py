"""Same inputs and seed give bit-identical results, whatever the threads and chunking."""

from __future__ import annotations

import numpy as np
import pytest

from aobake.methods.embree import EmbreeOptions, embree_ao
from aobake.methods.embree.estimator import estimate
from aobake.testing import scenes


@pytest.fixture(scope="module")
def scene():
    s, _ = scenes.sphere_on_ground(0.5, 3, gap=0.0, cells=10)
    return s


def test_same_seed_same_bits(scene):
    a = embree_ao(scene, n_rays=64, seed=5).ao
    b = embree_ao(scene, n_rays=64, seed=5).ao
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, embree_ao(scene, n_rays=64, seed=6).ao)


@pytest.mark.parametrize("tolerance", [None, 0.05])
def test_threads_and_chunks_do_not_change_bits(scene, tolerance):
    base = embree_ao(scene, n_rays=128, seed=1, threads=1, tolerance=tolerance)
    for threads, chunk in [(2, 1 << 20), (1, 1000), (2, 777), (3, 64)]:
        options = EmbreeOptions(n_rays=128, seed=1, threads=threads, tolerance=tolerance)
        other = estimate(scene, options, chunk_rays=chunk)
        np.testing.assert_array_equal(base.ao, other.ao)
        np.testing.assert_array_equal(base.rays, other.rays)


@pytest.mark.parametrize("method", ["embree", "bunnell"])
def test_more_threads_than_cores_run_as_the_cores_with_the_same_bits(scene, method):
    """The library's one rule, as the CLI's --threads: a count above the core count is
    the core count (numba cannot start more; Embree gains nothing)."""
    from aobake.methods import run

    options = {"n_rays": 32, "seed": 3} if method == "embree" else {}
    one = run(method, scene, {**options, "threads": 1}).ao
    np.testing.assert_array_equal(run(method, scene, {**options, "threads": 10_000}).ao, one)
    with pytest.raises(ValueError, match="threads must be an integer >= 1"):
        run(method, scene, {**options, "threads": 0})
