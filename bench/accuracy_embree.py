"""Closed-form accuracy of the Embree reference: measured error against exact answers.

Prints a Markdown table (used in the README). Run: ``python bench/accuracy_embree.py``.
Each row: the exact value, the mean |error| over 64 seeds, and the binomial standard
deviation sqrt(A(1-A)/N) that plain Monte Carlo would have, so the gain from the
Owen-scrambled Sobol directions is visible.
"""

from __future__ import annotations

import math

import numpy as np

from aobake.methods.embree import embree_ao
from aobake.testing import scenes
from aobake.testing.closed_forms import polygon_form_factor

SEEDS = 64


def _row(name, exact, estimates, n):
    err = np.abs(np.asarray(estimates) - exact)
    sigma = math.sqrt(max(exact * (1 - exact), 0.0) / n)
    rms = float(np.sqrt(np.mean(err**2)))
    gain = sigma / rms if rms > 0 else float("inf")
    print(
        f"| {name} | {n} | {exact:.6f} | {err.mean():.2e} | {err.max():.2e} | {sigma:.2e} | {gain:.1f}x |"
    )


def main() -> None:
    print("| case | rays | exact A | mean abs err | max abs err | binomial sigma | sigma / RMS |")
    print("|---|---|---|---|---|---|---|")
    for n in (16, 64, 256, 1024):
        s = scenes.receiver_under_disk(1.0, 0.7, sides=512)
        exact = polygon_form_factor(s.positions[1:513], [0, 0, 0], [0, 0, 1])
        est = [1 - embree_ao(s, n_rays=n, seed=k).ao[-3] for k in range(SEEDS)]
        _row("point under disk R=1, h=0.7 (cosine)", exact, est, n)
    for n in (64, 1024):
        s = scenes.receiver_under_disk(1.0, 0.7, sides=512)
        exact = 1 - 0.7 / math.hypot(0.7, 1.0)
        est = [1 - embree_ao(s, n_rays=n, seed=k, measure="uniform").ao[-3] for k in range(SEEDS)]
        _row("point under disk (uniform)", exact, est, n)
    for n in (64, 1024):
        s = scenes.parallel_plates(0.25, 4.0, cells=8)
        c = int(np.argmin(np.linalg.norm(s.positions, axis=1)))
        exact = 1 - (0.25 / 1.0) ** 2
        est = [1 - embree_ao(s, n_rays=n, seed=k, max_distance=1.0).ao[c] for k in range(SEEDS)]
        _row("plates gap 0.25, max distance 1", exact, est, n)
    s = scenes.sphere(1.0, 3, inward=True)
    _row("inside a closed sphere (all vertices)", 1.0, [1 - embree_ao(s, n_rays=64).ao.min()], 64)
    for scale in (1e-5, 1.0, 1e5):
        s = scenes.random_convex(3, 2, scale)
        _row(
            f"convex body at scale {scale:g} (all vertices)",
            0.0,
            [1 - embree_ao(s, n_rays=256).ao.min()],
            256,
        )


if __name__ == "__main__":
    main()
