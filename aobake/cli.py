"""Command-line interface: options, progress UI, exit codes and the one error boundary.

Imports only click at module level so ``aobake --help`` is instant; each command imports
the library inside its body. ``ao`` written by every command is accessibility 1 - A
(1 = fully open).
"""

from __future__ import annotations

import sys
from pathlib import Path

import click

from .errors import AobakeError

AO_CONVENTION = "The attribute `ao` holds 1 - A, the ambient factor (1 = fully open, 0 = fully occluded)."


class AobakeGroup(click.Group):
    """Turns :class:`AobakeError` into ``Error: <file>: <problem>`` and exit code 1."""

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except AobakeError as exc:
            raise click.ClickException(str(exc)) from None


def common_options(f):
    """--seed, --threads, --quiet: shared by every command that computes."""
    f = click.option("--quiet", "-q", is_flag=True, help="No progress bar or summary on stderr.")(f)
    f = click.option(
        "--threads", type=click.IntRange(min=1), default=None, help="Worker threads [default: all cores]."
    )(f)
    f = click.option(
        "--seed", type=click.IntRange(0, 2**63 - 1), default=0, show_default=True, help="Random seed."
    )(f)
    return f


@click.group(cls=AobakeGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="aobake")
def main():
    """Bake per-vertex ambient occlusion into meshes.

    The attribute `ao` holds 1 - A, the ambient factor (1 = fully open, 0 = fully
    occluded): the value renderers multiply by.
    """


@main.command()
@click.argument("mesh", type=click.Path(path_type=Path))
@click.option(
    "-o",
    "--output",
    required=True,
    multiple=True,
    type=click.Path(path_type=Path),
    help="Output .ply, .usda, .usdc or .usd (repeat for several formats from one bake).",
)
@click.option(
    "--method", type=click.Choice(["embree"]), default="embree", show_default=True, help="AO method."
)
@click.option("--rays", type=click.IntRange(min=1), default=256, show_default=True, help="Rays per vertex (max).")
@click.option(
    "--measure",
    type=click.Choice(["cosine", "uniform"]),
    default="cosine",
    show_default=True,
    help="cosine: 1/pi int V cos; uniform: solid-angle fraction.",
)
@click.option(
    "--max-distance", type=click.FloatRange(min=0, min_open=True), default=None, help="Ray length limit (mesh units)."
)
@click.option(
    "--bias",
    type=click.FloatRange(min=0),
    default=None,
    help="Ray origin offset (mesh units) [default: from float precision and edge length].",
)
@click.option(
    "--tolerance",
    type=click.FloatRange(min=0, min_open=True),
    default=None,
    help="Adaptive: stop a vertex once its 95% interval half-width is below this.",
)
@click.option("--color", is_flag=True, help="Also write ao as grey vertex colours.")
@click.option(
    "--up", type=click.Choice(["Y", "Z"]), default=None, help="USD stage up axis [default: the input's, else Y]."
)
@click.option(
    "--meters-per-unit",
    type=click.FloatRange(min=0, min_open=True),
    default=None,
    help="USD metersPerUnit [default: the input's, else 1].",
)
@common_options
def bake(mesh, output, method, rays, measure, max_distance, bias, tolerance, color, up, meters_per_unit, seed, threads, quiet):
    """Bake AO of MESH into OUTPUT as the per-vertex attribute `ao`.

    `ao` = 1 - A: 1 = fully open, 0 = fully occluded. MESH: PLY, OBJ, STL, OFF,
    GLB/glTF or USD; vertex count and order are kept.
    """
    from .pipeline import bake_file
    from .progress import make_progress

    report = bake_file(
        mesh,
        output,
        method=method,
        color=color,
        up_axis=up,
        meters_per_unit=meters_per_unit,
        progress=make_progress(quiet),
        n_rays=rays,
        measure=measure,
        max_distance=max_distance,
        bias=bias,
        seed=seed,
        tolerance=tolerance,
        threads=threads,
    )
    if not quiet:
        click.echo(report.summary(), err=True)


@main.command()
@click.argument("reference", type=click.Path(path_type=Path))
@click.argument("candidate", type=click.Path(path_type=Path))
@click.option(
    "--threshold", type=click.FloatRange(min=0), default=0.05, show_default=True, help="Report the share above this |error|."
)
@click.option("--worst", type=click.IntRange(min=0), default=10, show_default=True, help="List this many worst vertices.")
@click.option("--json", "json_path", type=click.Path(path_type=Path), default=None, help="Also write the numbers as JSON.")
@click.option(
    "--plot", "plot_path", type=click.Path(path_type=Path), default=None, help="Histogram + scatter PNG (needs matplotlib)."
)
@click.option(
    "--render", "render_path", type=click.Path(path_type=Path), default=None, help="PNG of REFERENCE, CANDIDATE, difference."
)
@click.option("--up", type=click.Choice(["Y", "Z"]), default=None, help="Up axis for --render [default: the file's, else Y].")
def compare(reference, candidate, threshold, worst, json_path, plot_path, render_path, up):
    """Error report of CANDIDATE against REFERENCE (bakes of one mesh: PLY, USD or .npy).

    Prints RMSE, MAE, bias, max and p50/p95/p99 of |error| (error = candidate -
    reference, on `ao` = 1 - A), the share of vertices above --threshold and the worst
    vertices.
    """
    from .pipeline import compare_files

    report = compare_files(
        reference,
        candidate,
        threshold=threshold,
        worst=worst,
        json_path=json_path,
        plot_path=plot_path,
        render_path=render_path,
        up=up,
    )
    click.echo(report.to_text())


@main.command()
@click.argument("mesh", type=click.Path(path_type=Path))
@click.option("-o", "--output", "out_dir", required=True, type=click.Path(path_type=Path), help="Directory for the results.")
@click.option(
    "--reference-rays", type=click.IntRange(min=16), default=4096, show_default=True, help="Rays of the Embree reference."
)
@click.option("--repeats", type=click.IntRange(min=1), default=3, show_default=True, help="Time each setting this often (best).")
@click.option("--no-plot", is_flag=True, help="Skip pareto.png (no matplotlib needed).")
@common_options
def sweep(mesh, out_dir, reference_rays, repeats, no_plot, seed, threads, quiet):
    """What accuracy costs in time: bake MESH over a grid of methods and settings.

    Each setting is timed and compared with a high-ray Embree reference (cached in
    OUTPUT). Writes sweep.csv, sweep.json and pareto.png (error against seconds,
    log-log, Pareto front marked) into OUTPUT and prints the table.
    """
    from .pipeline import sweep_file
    from .progress import make_progress
    from .sweep import to_markdown

    def on_row(row):
        if not quiet:
            click.echo(f"  {row.method:8s} {row.label:24s} {row.seconds:8.3f} s  RMSE {row.rmse:.4f}", err=True)

    rows = sweep_file(
        mesh,
        out_dir,
        reference_rays=reference_rays,
        seed=seed,
        threads=threads,
        repeats=repeats,
        plot=not no_plot,
        progress=make_progress(quiet),
        on_row=on_row,
    )
    click.echo(to_markdown(rows))


@main.command()
@click.argument("bake", type=click.Path(path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(path_type=Path), help="Output .png.")
@click.option("--view", type=click.Choice(["iso", "front", "side", "top"]), default="iso", show_default=True)
@click.option("--azimuth", type=float, default=None, help="Degrees about the up axis (overrides --view).")
@click.option("--elevation", type=click.FloatRange(-90, 90), default=None, help="Degrees above the horizon.")
@click.option("--size", type=click.IntRange(16, 8192), default=640, show_default=True, help="Image side in pixels.")
@click.option("--up", type=click.Choice(["Y", "Z"]), default=None, help="Up axis [default: the file's, else Y].")
def preview(bake, output, view, azimuth, elevation, size, up):
    """Render BAKE (a PLY or USD file with `ao`) to a PNG: AO as grey, white = open."""
    from .pipeline import preview_file

    preview_file(bake, output, size=size, up=up, view=view, azimuth=azimuth, elevation=elevation)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
