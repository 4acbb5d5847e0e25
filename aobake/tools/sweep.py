"""What accuracy costs in time: bake one surface over a grid of settings, time each, and
measure its error against a reference.

Numbers in, numbers out: no mesh files are read or written here (``pipeline.sweep_file``
does that); ``plot_sweep`` imports matplotlib lazily.
"""

from __future__ import annotations

import csv
import io
import json
import time
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass

import numpy as np

from ..io import atomic_write
from .plot import pyplot

#: Default grid: (method, label, options). Embree 4..1024 rays, with and without
#: adaptivity; Bunnell passes and opening parameter (when that method is available).
EMBREE_RAYS = (4, 16, 64, 256, 1024)
ADAPTIVE_TOLERANCES = (0.05, 0.02)
# (passes, theta, per-direction saturation); the last row: plain sums, for contrast
BUNNELL_GRID = ((1, 2.0, True), (1, 4.0, True), (1, 8.0, True), (2, 2.0, True), (1, 4.0, False))
FIELD_RESOLUTIONS = (8, 16, 32)
#: A lit scene's irradiance rows: Embree (shadow samples per area light, indirect paths),
#: its defaults (64, 256) among them; Bunnell's shadow passes after the distributing one
#: (2 is its default), and its default passes with the published shadowing for contrast.
LIGHT_EMBREE_GRID = ((4, 16), (16, 64), (64, 256), (256, 1024))
LIGHT_BUNNELL_PASSES = (0, 1, 2)


@dataclass(frozen=True)
class SweepRow:
    """One timed bake and its error against the reference (ao = 1 - A).

    ``seconds`` is the best of ``repeats`` runs; ``rays`` the rays cast (0 for methods
    that cast none). ``quantity`` ``"irradiance"``: a lit scene's row, its errors over
    vertices and RGB channels divided by the reference's RMS irradiance, so ``rmse`` is
    the relative RMSE sqrt(sum (E - E_ref)^2 / sum E_ref^2).
    """

    method: str
    label: str
    seconds: float
    rays: int
    rmse: float
    mae: float
    mean_error: float
    p99: float
    max_abs: float
    pareto: bool = False
    quantity: str = "ao"


def default_grid(methods: Iterable[str]) -> list[tuple[str, str, dict]]:
    """The settings a sweep tries for each available method."""
    methods = set(methods)
    grid: list[tuple[str, str, dict]] = []
    if "embree" in methods:
        grid += [("embree", f"rays={n}", {"n_rays": n}) for n in EMBREE_RAYS]
        grid += [
            ("embree", f"rays<=1024 tol={t:g}", {"n_rays": 1024, "tolerance": t})
            for t in ADAPTIVE_TOLERANCES
        ]
    if "bunnell" in methods:
        grid += [
            (
                "bunnell",
                f"passes={k} theta={th:g}" + ("" if d else " plain"),
                {"passes": k, "theta": th, "directional": d},
            )
            for k, th, d in BUNNELL_GRID
        ]
    return grid


def field_grid() -> list[tuple[str, str, dict]]:
    """Field settings tried when the mesh is used as an occluder over a ground."""
    return [
        ("field", f"N={r} cap raster (ground)", {"resolution": r}) for r in FIELD_RESOLUTIONS
    ] + [
        ("field", "N=16 cap embree (ground)", {"resolution": 16, "sampler": "embree"}),
        ("field", "N=16 table raster (ground)", {"resolution": 16, "model": "table"}),
    ]


def light_grid(methods: Iterable[str]) -> list[tuple[str, str, dict]]:
    """The irradiance settings a sweep of a lit scene tries for each available method
    (Embree: ``light_samples``/``indirect_rays``; Bunnell: ``disk_light`` keywords)."""
    methods = set(methods)
    grid: list[tuple[str, str, dict]] = []
    if "embree" in methods:
        grid += [
            ("embree", f"samples={s} paths={p}", {"light_samples": s, "indirect_rays": p})
            for s, p in LIGHT_EMBREE_GRID
        ]
    if "bunnell" in methods:
        grid += [
            ("bunnell", f"shadow passes={k}", {"shadow_passes": k}) for k in LIGHT_BUNNELL_PASSES
        ]
        grid += [
            (
                "bunnell",
                "shadow passes=2 published",
                {"shadow_passes": 2, "aimed": False, "faces_occlude": False},
            )
        ]
    return grid


def run_sweep(
    compute: Callable[[str, dict], tuple[np.ndarray, int]],
    reference: np.ndarray,
    grid: list[tuple[str, str, dict]],
    *,
    repeats: int = 1,
    on_row: Callable[[SweepRow], None] | None = None,
    quantity: str = "ao",
) -> list[SweepRow]:
    """Time ``compute(method, options) -> (values, rays)`` over ``grid`` and score each
    result against ``reference`` (same shape; every element one sample of the error).

    The first setting of each method is run once untimed first, so numba compilation
    and cache loading never count; a timed run during which numba still compiled (a
    setting that takes another code path) is run again. Returns the rows (marked
    ``quantity``) with ``pareto`` set on those no other row beats in both seconds and
    RMSE.
    """
    rows = []
    warm = set()
    for method, label, options in grid:
        if method not in warm:
            compute(method, dict(options))
            warm.add(method)
        best, ao, rays = float("inf"), None, 0
        for _ in range(max(1, repeats)):
            seconds, (ao, rays) = _timed(compute, method, options)
            best = min(best, seconds)
        err = np.asarray(ao, dtype=np.float64) - reference
        row = SweepRow(
            method=method,
            label=label,
            seconds=best,
            rays=int(rays),
            rmse=float(np.sqrt(np.mean(err**2))),
            mae=float(np.mean(np.abs(err))),
            mean_error=float(np.mean(err)),
            p99=float(np.percentile(np.abs(err), 99)),
            max_abs=float(np.abs(err).max()),
            quantity=quantity,
        )
        rows.append(row)
        if on_row is not None:
            on_row(row)
    return mark_pareto(rows)


def _timed(compute, method: str, options: dict):
    """``(seconds, compute(method, options))``, run again when numba compiled in the run."""
    from ..progress import CompileWatch

    for _ in range(2):
        with CompileWatch() as watch:
            t0 = time.perf_counter()
            out = compute(method, dict(options))
            seconds = time.perf_counter() - t0
        if not watch.count:
            break
    return seconds, out


def mark_pareto(rows: list[SweepRow]) -> list[SweepRow]:
    """Set ``pareto`` on rows that no other row beats in both time and RMSE."""
    out = []
    for r in rows:
        dominated = any(
            (o.seconds <= r.seconds and o.rmse <= r.rmse)
            and (o.seconds < r.seconds or o.rmse < r.rmse)
            for o in rows
        )
        out.append(SweepRow(**{**asdict(r), "pareto": not dominated}))
    return out


def to_markdown(rows: list[SweepRow]) -> str:
    """The table printed by ``aobake sweep`` (Pareto-optimal rows marked with *); a lit
    scene's irradiance rows follow in a table of their own."""
    ao = [r for r in rows if r.quantity == "ao"]
    lit = [r for r in rows if r.quantity != "ao"]
    text = _table(
        ao, "| method | settings | seconds | rays | RMSE | MAE | mean error | p99 | max | Pareto |"
    )
    if lit:
        text += (
            "\n\nIrradiance (errors over vertices and RGB, divided by the reference's RMS irradiance):\n\n"
            + _table(
                lit,
                "| method | settings | seconds | rays | rel. RMSE | rel. MAE | rel. mean error | rel. p99 | rel. max | Pareto |",
            )
        )
    return text


def _table(rows: list[SweepRow], header: str) -> str:
    lines = [header, "|---|---|---:|---:|---:|---:|---:|---:|---:|:---:|"]
    for r in rows:
        lines.append(
            f"| {r.method} | {r.label} | {r.seconds:.3f} | {r.rays} | {r.rmse:.4f} | {r.mae:.4f} | "
            f"{r.mean_error:+.4f} | {r.p99:.4f} | {r.max_abs:.4f} | {'*' if r.pareto else ''} |"
        )
    return "\n".join(lines)


def _fields(rows: list[SweepRow]) -> list[str]:
    """The columns written: ``quantity`` only when some row is not AO (an unlit scene's
    files are what they were before irradiance rows existed)."""
    names = list(SweepRow.__dataclass_fields__)
    return names if any(r.quantity != "ao" for r in rows) else [n for n in names if n != "quantity"]


def to_csv(rows: list[SweepRow]) -> str:
    buf = io.StringIO()
    fields = _fields(rows)
    writer = csv.DictWriter(buf, fieldnames=fields, lineterminator="\n")
    writer.writeheader()
    for r in rows:
        writer.writerow({k: v for k, v in asdict(r).items() if k in fields})
    return buf.getvalue()


def to_json(rows: list[SweepRow], meta: dict) -> str:
    fields = _fields(rows)
    out = [{k: v for k, v in asdict(r).items() if k in fields} for r in rows]
    return json.dumps({"meta": meta, "rows": out}, indent=2, allow_nan=False)


def plot_sweep(
    rows: list[SweepRow],
    path,
    *,
    title: str = "",
    ylabel: str = "RMSE of ao against the reference",
    front_name: str = "bake",
) -> None:
    """Error against seconds, log-log, one colour per method, the Pareto front drawn
    (``front_name`` names it; field rows have their own)."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 5))
    for method in sorted({r.method for r in rows}):
        pts = [r for r in rows if r.method == method]
        ax.scatter([r.seconds for r in pts], [max(r.rmse, 1e-6) for r in pts], label=method, s=30)
        for r in pts:
            ax.annotate(
                r.label,
                (r.seconds, max(r.rmse, 1e-6)),
                fontsize=7,
                xytext=(4, 3),
                textcoords="offset points",
            )
    # fields bake another scene (the ground under the mesh): a front of their own
    for scenario, style in (("mesh", "--"), ("field", ":")):
        front = sorted(
            (r for r in rows if r.pareto and (r.method == "field") == (scenario == "field")),
            key=lambda r: r.seconds,
        )
        if front:
            ax.plot(
                [r.seconds for r in front],
                [max(r.rmse, 1e-6) for r in front],
                color="k",
                lw=1,
                ls=style,
                label=f"Pareto front ({'field on the ground' if scenario == 'field' else front_name})",
            )
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.xaxis.set_minor_formatter(plt.NullFormatter())
    ax.yaxis.set_minor_formatter(plt.NullFormatter())
    ax.set_xlabel("seconds")
    ax.set_ylabel(ylabel)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    if title:
        ax.set_title(title)
    fig.tight_layout()
    with atomic_write(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)
