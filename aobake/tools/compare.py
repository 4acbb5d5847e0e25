"""Error reports between two bakes of the same mesh: arrays in, numbers out.

Reads and writes no mesh files (the CLI and pipeline do); ``plot_compare`` imports
matplotlib lazily and writes through ``io.atomic_write``.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io import atomic_write
from .plot import pyplot


@dataclass(frozen=True)
class WorstVertex:
    """One of the vertices with the largest |b - a|."""

    index: int
    position: tuple[float, float, float] | None
    a: float
    b: float

    @property
    def error(self) -> float:
        return self.b - self.a


@dataclass(frozen=True)
class Report:
    """Error statistics of bake ``b`` against bake ``a`` (``a`` is taken as the reference).

    Attributes
    ----------
    n_vertices : int
    rmse, mae, mean_error, max_abs : float
        Root-mean-square, mean absolute, mean signed (b - a) and largest absolute error
        (``mean_error``, not "bias": in ``bake``, ``--bias`` is the ray-origin offset).
    p50, p95, p99 : float
        Percentiles of |b - a|.
    threshold : float
    above : float
        Fraction of vertices with |b - a| > threshold.
    worst : tuple of WorstVertex
    """

    n_vertices: int
    rmse: float
    mae: float
    mean_error: float
    max_abs: float
    p50: float
    p95: float
    p99: float
    threshold: float
    above: float
    worst: tuple[WorstVertex, ...] = field(default=())
    names: tuple[str, str] = ("a", "b")

    def to_dict(self) -> dict:
        """JSON-ready dict of every number (worst vertices included)."""
        d = asdict(self)
        d["names"] = list(self.names)
        return d

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, allow_nan=False)

    def to_text(self) -> str:
        """A small aligned table for a terminal."""
        a, b = self.names
        lines = [
            f"{b} against {a}: {self.n_vertices} vertices (ao = 1 - A; error = {b} - {a})",
            f"  RMSE      {self.rmse:.6f}",
            f"  MAE       {self.mae:.6f}",
            f"  mean err  {self.mean_error:+.6f}",
            f"  max |err| {self.max_abs:.6f}",
            f"  p50/p95/p99 |err|  {self.p50:.6f} / {self.p95:.6f} / {self.p99:.6f}",
            f"  |err| > {self.threshold:g}: {100 * self.above:.2f}% of vertices",
        ]
        if self.worst:
            lines.append("  worst vertices:")
            lines.append(
                f"    {'index':>8}  {'position':>32}  {a[:10]:>10}  {b[:10]:>10}  {'error':>9}"
            )
            for w in self.worst:
                pos = (
                    ""
                    if w.position is None
                    else "(" + ", ".join(f"{c:.4g}" for c in w.position) + ")"
                )
                lines.append(
                    f"    {w.index:>8}  {pos:>32}  {w.a:>10.5f}  {w.b:>10.5f}  {w.error:>+9.5f}"
                )
        return "\n".join(lines)


def compare_ao(
    a,
    b,
    *,
    positions=None,
    threshold: float = 0.05,
    worst: int = 10,
    names: tuple[str, str] = ("a", "b"),
) -> Report:
    """Compare two per-vertex AO arrays of the same mesh.

    Parameters
    ----------
    a, b : (n,) float
        AO values (``a`` is the reference); NaN or inf are refused.
    positions : (n, 3) float, optional
        Vertex positions, reported for the worst vertices.
    threshold : float
        Report the fraction of vertices with |b - a| above this.
    worst : int
        How many of the largest errors to list.
    names : (str, str)
        Labels for the text report.

    Raises
    ------
    InputError
        Different vertex counts, or non-finite values.
    """
    a = np.asarray(a, dtype=np.float64).reshape(-1)
    b = np.asarray(b, dtype=np.float64).reshape(-1)
    if a.shape != b.shape:
        raise InputError(
            names[1],
            f"has {b.size} vertices but {names[0]} has {a.size}; compare bakes of the same mesh",
        )
    if a.size == 0:
        raise InputError(names[0], "has no vertices")
    for name, x in zip(names, (a, b), strict=True):
        if not np.isfinite(x).all():
            raise InputError(name, f"{int((~np.isfinite(x)).sum())} non-finite AO values")
    err = b - a
    abs_err = np.abs(err)
    p50, p95, p99 = np.percentile(abs_err, [50, 95, 99])
    order = np.argsort(-abs_err, kind="stable")[: max(0, int(worst))]
    pos = None if positions is None else np.asarray(positions, dtype=np.float64)
    rows = tuple(
        WorstVertex(
            int(i),
            None if pos is None else tuple(float(c) for c in pos[i]),
            float(a[i]),
            float(b[i]),
        )
        for i in order
    )
    return Report(
        n_vertices=int(a.size),
        rmse=float(np.sqrt(np.mean(err**2))),
        mae=float(abs_err.mean()),
        mean_error=float(err.mean()),
        max_abs=float(abs_err.max()),
        p50=float(p50),
        p95=float(p95),
        p99=float(p99),
        threshold=float(threshold),
        above=float(np.mean(abs_err > threshold)),
        worst=rows,
        names=(str(names[0]), str(names[1])),
    )


def plot_compare(a, b, path: str | Path, *, names: tuple[str, str] = ("a", "b")) -> None:
    """Write a PNG: histogram of b - a and scatter of b against a.

    Raises
    ------
    AobakeError
        matplotlib is not installed.
    """
    plt = pyplot()
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    fig, (h, s) = plt.subplots(1, 2, figsize=(10, 4.2))
    err = b - a
    lim = max(float(np.abs(err).max()), 1e-6)
    h.hist(err, bins=80, range=(-lim, lim), color="0.3")
    h.set_xlabel(f"{names[1]} - {names[0]} (ao)")
    h.set_ylabel("vertices")
    h.set_yscale("log")
    h.set_title(f"error: RMSE {np.sqrt(np.mean(err**2)):.4f}")
    s.scatter(a, b, s=2, alpha=0.3, color="0.2", rasterized=True)
    s.plot([0, 1], [0, 1], color="tab:red", lw=1)
    s.set_xlim(0, 1)
    s.set_ylim(0, 1)
    s.set_aspect("equal")
    s.set_xlabel(f"{names[0]} ao")
    s.set_ylabel(f"{names[1]} ao")
    fig.tight_layout()
    with atomic_write(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)
