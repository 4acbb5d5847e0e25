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
        import threading

        from . import progress

        if threading.current_thread() is threading.main_thread():
            progress.install_interrupt_handler()  # Ctrl-C during numba compilation is not lost
        try:
            return super().invoke(ctx)
        except AobakeError as exc:
            raise click.ClickException(str(exc)) from None
        except Exception:
            # after a Ctrl-C that Python dropped (progress.install_interrupt_handler),
            # numba may fail in its own way (a half-compiled library): that is the abort
            if progress.interrupted():
                raise click.Abort() from None
            raise


class FieldSpec(click.ParamType):
    """``FIELD.npz[@tx,ty,tz[,rx,ry,rz]]``: a field file and where its occluder goes.

    Translation in mesh units; rotation in degrees about the fixed x, then y, then z
    axes, applied before the translation (``aobake.methods.fields.rigid_transform``). The text
    after the last ``@`` is read as the placement only when it is 3 or 6 numbers, so
    paths containing ``@`` still work.
    """

    name = "FIELD[@tx,ty,tz[,rx,ry,rz]]"

    def convert(self, value, param, ctx):
        if isinstance(value, tuple):
            return value
        path, sep, tail = str(value).rpartition("@")
        if sep:
            parts = tail.split(",")
            try:
                numbers = tuple(float(t) for t in parts)
            except ValueError:
                numbers = None
            if numbers is not None:
                if len(numbers) not in (3, 6):
                    self.fail(f"{value!r}: give 3 numbers (tx,ty,tz) or 6 (tx,ty,tz,rx,ry,rz)", param, ctx)
                if not all(abs(v) < float("inf") for v in numbers):
                    self.fail(f"{value!r}: the placement must be finite numbers", param, ctx)
                return Path(path), numbers
        return Path(str(value)), None


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


# Options each --method takes (library keyword names); "seed" is silently unused by bunnell.
METHOD_OPTIONS = {
    "embree": ("n_rays", "measure", "max_distance", "bias", "seed", "tolerance", "threads"),
    "bunnell": ("measure", "max_distance", "passes", "theta", "near", "directional", "threads"),
}
FLAGS = {"n_rays": "--rays"}


def _method_options(method: str, **given) -> dict:
    """The options ``method`` takes; a usage error for one set on the command line that it
    does not take. Options left at a default of None are not passed, so the library's
    defaults apply."""
    ctx = click.get_current_context()
    source = {"n_rays": "rays"}
    wanted = METHOD_OPTIONS[method]
    out = {}
    for name, value in given.items():
        explicit = ctx.get_parameter_source(source.get(name, name)) not in (
            click.core.ParameterSource.DEFAULT,
            click.core.ParameterSource.DEFAULT_MAP,
        )
        if name not in wanted:
            if explicit and name != "seed":
                flag = FLAGS.get(name, "--" + name.replace("_", "-"))
                raise click.UsageError(f"{flag} does not apply to --method {method}")
            continue
        if value is None:
            continue
        out[name] = value
    return out


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
    "--method",
    type=click.Choice(["embree", "bunnell"]),
    default="embree",
    show_default=True,
    help="embree: ray casting (the reference); bunnell: disk and polygon form factors, no rays.",
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
@click.option(
    "--passes", type=click.IntRange(min=1), default=None, help="bunnell: occlusion passes [default: 1]."
)
@click.option(
    "--theta",
    type=click.FloatRange(min=0, min_open=True),
    default=None,
    help="bunnell: opening parameter of the disk tree (larger = slower, more exact) [default: 2].",
)
@click.option(
    "--near",
    type=click.FloatRange(min=0),
    default=None,
    help="bunnell: disks closer than sqrt(NEAR * area) become exact polygons (0 = disks only) [default: 4].",
)
@click.option(
    "--directional/--no-directional",
    default=None,
    help="bunnell: per-direction saturation, layers stacked in one direction count once "
    "[default: on; off = the plain sum].",
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
@click.option(
    "--field",
    "fields",
    multiple=True,
    type=FieldSpec(),
    help="An AO field (from `aobake field`) of a rigid occluder, optionally placed: "
    "FIELD.npz@tx,ty,tz[,rx,ry,rz] (mesh units; degrees about x, then y, then z). "
    "Repeatable; each multiplies ao by its 1 - A_k.",
)
@common_options
def bake(
    mesh, output, method, rays, measure, max_distance, bias, tolerance, passes, theta, near, directional,
    color, up, meters_per_unit, fields, seed, threads, quiet
):
    """Bake AO of MESH into OUTPUT as the per-vertex attribute `ao`.

    `ao` = 1 - A: 1 = fully open, 0 = fully occluded. MESH: PLY, OBJ, STL, OFF,
    GLB/glTF or USD; vertex count and order are kept. With --field, the mesh's own AO
    is multiplied by each occluder's: 1 - A = (1 - A_self) prod (1 - A_k).
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
        fields=fields,
        **_method_options(
            method, n_rays=rays, measure=measure, max_distance=max_distance, bias=bias, seed=seed,
            tolerance=tolerance, passes=passes, theta=theta, near=near, directional=directional,
            threads=threads,
        ),
    )
    if not quiet:
        click.echo(report.summary(), err=True)


class NumberRange(click.FloatRange):
    """``click.FloatRange`` that refuses NaN, and infinity unless ``finite=False`` (usage
    errors, as :func:`aobake.options.validate` would refuse them)."""

    def __init__(self, *args, finite: bool = True, **kwargs):
        super().__init__(*args, **kwargs)
        self.finite = finite

    def convert(self, value, param, ctx):
        value = super().convert(value, param, ctx)
        if value != value or (self.finite and value in (float("inf"), float("-inf"))):
            self.fail(f"{value} is not a {'finite ' if self.finite else ''}number.", param, ctx)
        return value


def _click_type(spec):
    """The click type of an option field (:class:`aobake.options.Spec`)."""
    if spec.choices is not None:
        return click.Choice(list(spec.choices))
    if spec.kind not in (int, float):
        return None
    bounds = {"min": spec.low, "max": spec.high, "min_open": spec.low_open, "max_open": spec.high_open}
    if spec.kind is int:
        return click.IntRange(**bounds)
    return NumberRange(**bounds, finite=spec.finite)


def options_from(options_class, skip: tuple[str, ...] = ()):
    """Click options from the fields of a method's options class (:mod:`aobake.options`):
    flag, type, range, default and help are spelled there once. A default of None shows
    what None means: "[default: all cores]"."""
    from .options import flag, specs

    def decorate(f):
        for name, (spec, default) in reversed(specs(options_class).items()):
            if name in skip:
                continue
            kw = {"default": default, "help": spec.help}
            if default is None and spec.none:
                kw["help"] = spec.help.rstrip(".") + f" [default: {spec.none}]."
            else:
                kw["show_default"] = True
            long = flag(name, spec)
            if spec.kind is bool:
                f = click.option(f"{long}/--no-{long[2:]}", name, **kw)(f)
            else:
                f = click.option(long, name, type=_click_type(spec), **kw)(f)
        return f

    return decorate


def _field_options(f):
    from .methods.fields.options import FieldOptions

    return options_from(FieldOptions)(f)


@main.command("field")
@click.argument("occluder", type=click.Path(path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(path_type=Path), help="Output FIELD.npz.")
@_field_options
@click.option("--quiet", "-q", is_flag=True, help="No progress bar or summary on stderr.")
def field_command(occluder, output, quiet, **options):
    """Fit the ambient occlusion field of the rigid OCCLUDER into FIELD.npz.

    Use it with `aobake bake RECEIVER -o OUT --field FIELD.npz[@tx,ty,tz[,rx,ry,rz]]`:
    the occluder's contact shadows on any receiver, at the cost of a table lookup.
    """
    from .pipeline import fit_field_file
    from .progress import make_progress

    report = fit_field_file(occluder, output, progress=make_progress(quiet), **options)
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
@click.option(
    "--no-fields",
    is_flag=True,
    help="Skip the AO-field rows (MESH as one rigid occluder over a ground grid; skip them for scenes with a floor).",
)
@click.option(
    "--up", type=click.Choice(["Y", "Z"]), default=None, help="Up axis for the field rows' ground [default: the file's, else Y]."
)
@common_options
def sweep(mesh, out_dir, reference_rays, repeats, no_plot, no_fields, up, seed, threads, quiet):
    """What accuracy costs in time: bake MESH over a grid of methods and settings.

    Each setting is timed and compared with a high-ray Embree reference (cached in
    OUTPUT). Rows marked "(ground)" use MESH as a rigid occluder on a ground grid and
    score AO fields on the ground. Writes sweep.csv, sweep.json and pareto.png (error
    against seconds, log-log, Pareto fronts marked) into OUTPUT and prints the table.
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
        fields=not no_fields,
        up=up,
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
