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
from .methods import METHODS
from .tools.views import VIEWS

AO_CONVENTION = "The attribute `ao` holds 1 - A, the ambient factor (1 = fully open, 0 = fully occluded)."


class AobakeGroup(click.Group):
    """Turns :class:`AobakeError` into ``Error: <file>: <problem>`` and exit code 1.

    Warnings (numpy, trimesh's log, USD's stderr) are held while the command runs:
    shown as ``Warning: ...`` lines when it succeeds, dropped when it fails (the
    ``Error:`` line is then the only output). SIGTERM ends it like Ctrl-C (temporary
    files removed), with exit code 143.
    """

    def invoke(self, ctx):
        import threading

        from . import progress
        from .precompile import fixed_mmap_threshold

        if threading.current_thread() is threading.main_thread():
            progress.install_interrupt_handler()  # Ctrl-C during numba compilation is not lost
        fixed_mmap_threshold()
        with _held_warnings() as held:
            try:
                result = super().invoke(ctx)
            except AobakeError as exc:
                error = click.ClickException(str(exc))
                error.exit_code = getattr(exc, "exit_code", 1)
                raise error from None
            except progress.Terminated:
                ctx.exit(128 + 15)
            except Exception:
                # after a Ctrl-C that Python dropped (progress.install_interrupt_handler),
                # numba may fail in its own way (a half-compiled library): that is the abort
                if progress.interrupted():
                    raise click.Abort() from None
                raise
        for line in dict.fromkeys(held):  # once each, in order
            click.echo(f"Warning: {line}", err=True)
        return result

    def main(self, args=None, *rest, **kwargs):
        """click's ``main``. As the process's own command line (``aobake ...``, ``python -m
        aobake``: ``args`` None, standalone) it ends the process at once
        (:func:`_end_process`); given arguments (tests, scripts) it is click's."""
        if args is not None or rest or not kwargs.get("standalone_mode", True):
            return super().main(args, *rest, **kwargs)
        try:
            return super().main(args, **kwargs)
        except SystemExit as exc:
            _end_process(exc)
            raise


def _end_process(exc: SystemExit) -> None:
    """End the process with ``exc``'s code as ``sys.exit`` would, less Python's
    finalisation: the atexit functions run and the standard streams are flushed, then
    ``os._exit``. Deleting numba's and LLVM's many objects one by one (and collecting
    them) cost ~0.3 s of CPU at the end of every bake (docs/process.md); the system
    frees the memory at once. Returns (for the usual exit) when another thread is still
    running, which Python would wait for, or when a stream cannot be flushed."""
    import threading

    code = exc.code
    if code is not None and not isinstance(code, int):  # a message: Python prints it
        return
    if threading.current_thread() is not threading.main_thread() or any(
        t is not threading.main_thread() and not t.daemon and t.is_alive() for t in threading.enumerate()
    ):
        return
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (OSError, ValueError):
        return
    import atexit
    import os

    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code or 0)


def _held_warnings():
    """Context manager: collect Python warnings and WARNING log records (trimesh) into
    a list of one-line messages instead of printing them."""
    import contextlib
    import logging
    import warnings

    class Held(logging.Handler):
        def emit(self, record):
            held.append(" ".join(record.getMessage().split()))

    held: list[str] = []

    @contextlib.contextmanager
    def hold():
        log = Held(logging.WARNING)
        root = logging.getLogger()
        root.addHandler(log)
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("default")
                yield held
        finally:
            root.removeHandler(log)
            held[:0] = [" ".join(str(w.message).split()) for w in caught]

    return hold()


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


class GroundSpec(click.ParamType):
    """``auto`` or a finite height in mesh units (``--ground``)."""

    name = "auto|HEIGHT"

    def convert(self, value, param, ctx):
        from .ground import parse_ground

        try:
            return parse_ground(value)
        except ValueError as exc:
            self.fail(str(exc), param, ctx)


def compile_notice(quiet: bool):
    """A :class:`aobake.progress.CompileWatch` that says "compiling kernels (first run
    only) ..." on stderr when numba starts compiling, unless ``quiet``."""
    from .progress import CompileWatch

    return CompileWatch(None if quiet else sys.stderr)


def common_options(f):
    """--seed, --threads, --quiet: shared by every command that computes (seed and threads
    as :mod:`aobake.options` defines them)."""
    from .options import seed_option, threads_option

    f = click.option("--quiet", "-q", is_flag=True, help="No progress bar or summary on stderr.")(f)
    for name, field in (("threads", threads_option()), ("seed", seed_option())):
        spec = field.metadata["spec"]
        f = _option(name, spec, field.default)(f)
    return f


@click.group(cls=AobakeGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="aobake")
def main():
    """Bake per-vertex ambient occlusion into meshes.

    The attribute `ao` holds 1 - A, the ambient factor (1 = fully open, 0 = fully
    occluded): the value renderers multiply by.
    """


class NumberRange(click.FloatRange):
    """``click.FloatRange`` that refuses NaN, and infinity unless ``finite=False`` (usage
    errors, as :func:`aobake.options.validate` would refuse them)."""

    def __init__(self, *args, finite: bool = True, **kwargs):
        super().__init__(*args, **kwargs)
        self.finite = finite
        if self.min is None and self.max is None:
            self.name = "float"  # the metavar: FLOAT, not FLOAT RANGE

    def convert(self, value, param, ctx):
        value = super().convert(value, param, ctx)
        if value != value or (self.finite and value in (float("inf"), float("-inf"))):
            self.fail(f"{value} is not a {'finite ' if self.finite else ''}number.", param, ctx)
        return value

    def _describe_range(self) -> str:
        # no bounds: say nothing (click would print "x<=None")
        if self.min is None and self.max is None:
            return ""
        return super()._describe_range()


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


def _method_fields() -> dict:
    """``{field: (Spec, {method: default})}`` over every method's options class, in the
    order the classes list them (the methods that take a field are its dict's keys)."""
    from .methods import METHODS, options_class
    from .options import specs

    fields = {}
    for method in METHODS:
        for name, (spec, default) in specs(options_class(method)).items():
            fields.setdefault(name, (spec, {}))[1][method] = default
    return fields


def _shown(spec, default) -> str:
    """A field's default as ``--help`` shows it: "2", "on", "unbounded"."""
    if default is None:
        return spec.none or "none"
    if spec.kind is bool:
        return "on" if default else "off"
    return f"{default:g}" if spec.kind is float else str(default)


def _clamp_threads(ctx, param, value):
    """``--threads`` above the core count: the core count, with a note on stderr (more
    threads than cores only costs memory, and the numba methods cannot start them)."""
    import os

    cores = os.cpu_count() or 1
    if value is not None and value > cores:
        click.echo(f"Note: --threads {value}: this machine has {cores} cores; using {cores}.", err=True)
        return cores
    return value


def _option(name: str, spec, default, *, set_default: bool = True, text: str | None = None, show: bool = True):
    """The click option of an option field: flag, type, range, help and shown default from
    its :class:`aobake.options.Spec`. ``set_default=False`` leaves the click default None,
    so a command can tell what the user set (the options class fills in the rest)."""
    from .options import flag

    decl = flag(name, spec)
    if spec.kind is bool:
        decl = f"{decl}/--no-{decl[2:]}"
    text = text or spec.help
    shown = set_default and default is not None
    if not shown and show:  # click would show None: say what it stands for
        text = text.rstrip(".") + f" [default: {_shown(spec, default)}]."
    return click.option(
        decl,
        name,
        type=None if spec.kind is bool else _click_type(spec),
        default=default if set_default else None,
        show_default=shown,
        help=text,
        callback=_clamp_threads if name == "threads" else None,
    )


def options_from(options_class, skip: tuple[str, ...] = ()):
    """Click options from the fields of an options class (:mod:`aobake.options`)."""
    from .options import specs

    def decorate(f):
        for name, (spec, default) in reversed(specs(options_class).items()):
            if name not in skip:
                f = _option(name, spec, default)(f)
        return f

    return decorate


def method_options(f):
    """One option per field of the methods' options classes: flag, type, default and help
    come from the classes (each spelled once there). Their value here is None unless the
    user sets one, so the command can tell what was set; the method's class fills in the
    rest. Help names the methods that take an option, and each one's default when they
    differ."""
    from .methods import METHODS

    for name, (spec, defaults) in reversed(_method_fields().items()):
        owners = list(defaults)
        text = spec.help if len(owners) == len(METHODS) else f"{'/'.join(owners)}: {spec.help}"
        shown = {_shown(spec, d) for d in defaults.values()}
        if len(shown) > 1:
            text = text.rstrip(".") + " [default: " + ", ".join(f"{m} {_shown(spec, d)}" for m, d in defaults.items()) + "]."
            f = _option(name, spec, None, set_default=False, text=text, show=False)(f)
        else:
            f = _option(name, spec, next(iter(defaults.values())), set_default=False, text=text)(f)
    return f


def _method_options(method: str, given: dict) -> dict:
    """What the user set for ``method``: one rule for every option, a usage error when
    ``method`` does not take it (``--seed 3 --method bunnell``), whatever its value."""
    from .methods import options_class
    from .options import flag, specs

    fields = _method_fields()
    takes = specs(options_class(method))
    out = {}
    for name, value in given.items():
        if value is None:
            continue
        if name not in takes:
            raise click.UsageError(f"{flag(name, fields[name][0])} does not apply to --method {method}")
        out[name] = value
    return out


def _bake_settings(
    method, color, channel, weld, up, meters_per_unit, fields, time_code, overlay, given, ground=None
) -> dict:
    """The arguments of :func:`aobake.pipeline.bake_file` (and of a batch's
    :class:`aobake.batch.Settings`) from the bake options; ``options``: the method's."""
    if color and channel:
        raise click.UsageError("--color and --channel both write the vertex colours; give one")
    selection = {key: tuple(given.pop(key, None) or ()) for key in ("receivers", "occluders")}
    light = _light_settings(given)
    return dict(
        **{key: patterns for key, patterns in selection.items() if patterns},
        **light,
        method=method,
        options=_method_options(method, given),
        color=color,
        channel=channel,
        weld=weld,
        up_axis=up,
        meters_per_unit=meters_per_unit,
        fields=tuple(fields),
        time=time_code,
        overlay=overlay,
        ground=ground,
    )


def _light_settings(given: dict) -> dict:
    """The light arguments of :func:`aobake.pipeline.bake_file` taken out of ``given``;
    only those that differ from their defaults, so an AO bake's settings stay as they were."""
    effects = given.pop("effects", None) or "auto"
    lights = tuple(given.pop("lights", None) or ())
    scene_lights = not given.pop("no_scene_lights", False)
    split = bool(given.pop("split_irradiance", False))
    exposure = given.pop("exposure", None) or 0.0
    out = {}
    if effects != "auto":
        out["effects"] = effects
    if lights:
        out["lights"] = lights
    if not scene_lights:
        out["scene_lights"] = False
    if split:
        out["split_irradiance"] = True
    if exposure:
        out["exposure"] = exposure
    return out


def _effects(ctx, param, value):
    """``--effects``: ``auto`` or a comma-separated subset of the effects, as a tuple."""
    from .constants import EFFECTS

    if value is None or value.strip() == "auto":
        return None
    names = tuple(t.strip() for t in value.split(",") if t.strip())
    bad = [n for n in names if n not in EFFECTS]
    if bad or not names:
        raise click.BadParameter(f"{value!r}: give auto or a comma-separated list of {', '.join(EFFECTS)}")
    return names


def _light_spec(ctx, param, value):
    """``--light``: each spec parsed now, so a typo is a usage error before any work."""
    if not value:
        return ()
    from .io.lights import parse_light_spec

    for k, text in enumerate(value, 1):
        try:
            parse_light_spec(text, k)
        except ValueError as exc:
            raise click.BadParameter(str(exc)) from None
    return tuple(value)


LIGHT_OPTIONS = [
    click.option(
        "--effects",
        default=None,
        callback=_effects,
        metavar="auto|LIST",
        help="What to compute: auto (what the scene calls for: ao always, direct light where it has lights "
        "or emitters, indirect where some albedo is above zero) or a list such as ao,direct [default: auto].",
    ),
    click.option(
        "--light",
        "lights",
        multiple=True,
        callback=_light_spec,
        metavar="SPEC",
        help="Add a light: distant:DX,DY,DZ[:E[:R,G,B]] (towards the light; irradiance E) or "
        "point:X,Y,Z[:I[:R,G,B]] (intensity I). Repeatable.",
    ),
    click.option("--no-scene-lights", is_flag=True, help="Ignore the file's own lights (its materials still count)."),
    click.option(
        "--exposure",
        type=NumberRange(),
        default=None,
        help="Stops applied to the lit colour --color writes for a lit scene [default: 0].",
    ),
    click.option(
        "--split-irradiance",
        is_flag=True,
        help="Lit scenes: also write irradiance_direct and irradiance_indirect beside irradiance.",
    ),
]


def bake_options(f):
    """--method, its options (--seed and --threads among them), --color, --up,
    --meters-per-unit, --field and --quiet: what `bake` takes and `batch` applies to every
    input."""
    for decorate in reversed(_BAKE_OPTIONS):
        f = decorate(f)
    return f


_BAKE_OPTIONS = [
    click.option(
        "--method",
        type=click.Choice(METHODS),
        default=METHODS[0],
        show_default=True,
        help="embree: ray casting (the reference); bunnell: disk and polygon form factors, no rays.",
    ),
    method_options,
    click.option(
        "--color", is_flag=True, help="Also write ao as grey vertex colours (sRGB bytes in PLY, linear in USD and glTF)."
    ),
    click.option(
        "--channel",
        type=click.Choice(["R", "G", "B", "A"]),
        default=None,
        help="Write ao (linear) into this channel of the input's vertex colours, keeping the others (PLY, glTF; USD input: displayColor, A = displayOpacity).",
    ),
    click.option(
        "--weld", is_flag=True, help="Bake with coincident vertices merged (STL soups, split seams); written per input vertex."
    ),
    click.option(
        "--up",
        type=click.Choice(["Y", "Z"]),
        default=None,
        help="Up axis: USD stage, PLY comment, glTF root turned to Y-up [default: the input's, else Y].",
    ),
    click.option(
        "--meters-per-unit",
        type=NumberRange(min=0, min_open=True),
        default=None,
        help="USD metersPerUnit, PLY comment, glTF root scale [default: the input's, else 1].",
    ),
    click.option(
        "--overlay/--no-overlay",
        default=None,
        help="USD input to .usda/.usdc/.usd: write a layer over the source holding only ao "
        "(sublayers it by relative path), or a full flattened copy with ao "
        "[default: overlay]. .usdz is always a flattened package.",
    ),
    click.option(
        "--time",
        "time_code",
        type=NumberRange(),
        default=None,
        help="USD input: read animated points and transforms at this time code "
        "[default: the default time; geometry with only time samples: its earliest sample].",
    ),
    click.option(
        "--field",
        "fields",
        multiple=True,
        type=FieldSpec(),
        help="An AO field (from `aobake field`) of a rigid occluder, optionally placed: "
        "FIELD.npz@tx,ty,tz[,rx,ry,rz] (mesh units; degrees about x, then y, then z). "
        "Repeatable; each multiplies ao by its 1 - A_k.",
    ),
    click.option(
        "--receivers",
        multiple=True,
        metavar="PATTERN",
        help="Bake only the parts this glob matches (USD prim path, else glTF node/OBJ object/file name); "
        "the others keep the input's ao, else 1. Repeatable.",
    ),
    click.option(
        "--occluders",
        multiple=True,
        metavar="PATTERN",
        help="Only the parts this glob matches cast occlusion; the others are left out of the scene "
        "(still written). Repeatable.",
    ),
    click.option(
        "--ground",
        type=GroundSpec(),
        default=None,
        help="An infinite occluding plane perpendicular to the up axis, at the lowest vertex (auto) "
        "or at HEIGHT (mesh units); it receives nothing [default: none].",
    ),
    *LIGHT_OPTIONS,
    click.option("--quiet", "-q", is_flag=True, help="No progress bar or summary on stderr."),
]


@main.command()
@click.argument("mesh", type=click.Path(path_type=Path))
@click.option(
    "-o",
    "--output",
    required=True,
    multiple=True,
    type=click.Path(path_type=Path),
    help="Output .ply, .usda, .usdc, .usd, .usdz, .gltf or .glb (repeat for several formats from one bake).",
)
@bake_options
def bake(
    mesh, output, method, color, channel, weld, up, meters_per_unit, overlay, time_code, fields, ground, quiet, **given
):
    """Bake AO of MESH into OUTPUT as the per-vertex attribute `ao`.

    `ao` = 1 - A: 1 = fully open, 0 = fully occluded. MESH: PLY, OBJ, STL, OFF,
    GLB/glTF or USD; vertex count and order are kept. With --field, the mesh's own AO
    is multiplied by each occluder's: 1 - A = (1 - A_self) prod (1 - A_k). A USD
    input baked to USD gives an overlay: the source with primvars:ao added, by layering.
    """
    from . import precompile
    from .pipeline import bake_file
    from .progress import make_progress

    settings = _bake_settings(
        method, color, channel, weld, up, meters_per_unit, fields, time_code, overlay, given, ground
    )
    options = settings.pop("options")
    # a cold cache: the largest kernel compiles in a helper process, on another core
    with compile_notice(quiet), precompile.enabled():
        report = bake_file(mesh, output, progress=make_progress(quiet), **settings, **options)
    if not quiet:
        click.echo(report.summary(), err=True)


@main.command("plan")
@click.argument("scene", type=click.Path(path_type=Path))
@click.option(
    "--method",
    type=click.Choice(METHODS),
    default=METHODS[0],
    show_default=True,
    help="The method the bake would use (its rays and settings).",
)
@method_options
@LIGHT_OPTIONS[0]
@LIGHT_OPTIONS[1]
@LIGHT_OPTIONS[2]
@click.option("--time", "time_code", type=NumberRange(), default=None, help="USD input: the time code to read.")
def plan(scene, method, effects, lights, no_scene_lights, time_code, **given):
    """Say which effects baking SCENE calls for and why, which lights reach which
    receivers, and how many rays it would cast. Computes nothing.

    AO always; direct light when the scene has lights or emitters (its own, or --light);
    indirect light when, besides, some albedo is above zero and --bounces is above 0.
    """
    import warnings

    from .pipeline import plan_file

    options = _method_options(method, {k: v for k, v in given.items() if k not in ("threads", "seed")})
    with warnings.catch_warnings():
        warnings.simplefilter("default")
        surface, shading, result = plan_file(
            scene, method=method, effects=effects or "auto", lights=lights, scene_lights=not no_scene_lights,
            time=time_code, **options,
        )  # fmt: skip
    click.echo(f"{scene.name}: {surface.n_vertices} vertices, {surface.n_faces} triangles, --method {method}")
    click.echo(f"albedo: {shading.sources.get('albedo', '?')}; emission: {shading.sources.get('emission', '?')}; "
               f"lights: {shading.sources.get('lights', '?')}")  # fmt: skip
    click.echo(result.report())


@main.command()
@click.argument("paths", nargs=-1, required=True)
@click.option(
    "-o", "--output", "outdir", required=True, type=click.Path(path_type=Path), help="Output directory (created)."
)
@click.option(
    "--to",
    "formats",
    default="ply,usda",
    show_default=True,
    help="Formats written per input, comma-separated (ply, usda, usdc, usd): OUTDIR/<relative path>/<stem>.<ext>.",
)
@click.option(
    "--workers", type=click.IntRange(min=1), default=None, help="Local worker processes [default: one per core]."
)
@click.option("--scheduler", default=None, help="Use a running Dask cluster: tcp://HOST:PORT of its scheduler.")
@click.option(
    "--split",
    type=click.IntRange(min=1),
    default=1,
    show_default=True,
    help="Bake each mesh as K vertex ranges on K tasks (embree only; bit-identical to an unsplit bake).",
)
@click.option(
    "--retries",
    type=click.IntRange(min=0),
    default=2,
    show_default=True,
    help="Rerun an input whose worker died or failed unexpectedly this often (a bad mesh is not retried).",
)
@click.option("--force", is_flag=True, help="Bake every input, also those the manifest records as up to date.")
@click.option(
    "--emit-commands",
    is_flag=True,
    help="Print one `aobake bake` command per input that is not up to date instead of baking (for render farms, xargs -P).",
)
@bake_options
def batch(
    paths, outdir, formats, workers, scheduler, split, retries, force, emit_commands,
    method, color, channel, weld, up, meters_per_unit, overlay, time_code, fields, ground, quiet, **given,
):  # fmt: skip
    """Bake every mesh PATHS name into OUTDIR on a Dask cluster, skipping what is up to date.

    PATHS: mesh files, directories (searched recursively), .txt/.lst files listing
    paths, or glob patterns. Every `bake` option applies to every input. Runs on a local
    cluster of worker processes by default, or on --scheduler. An input is skipped when
    its content, the options and the aobake version match OUTDIR/manifest.json; each
    input's status, error, vertices, rays, seconds, worker and output hashes are recorded
    there (and in manifest.csv). Exit code 1 when any input failed.
    """
    from .batch import Settings, run_batch
    from .batch import emit_commands as emit
    from .progress import NullBatchBar, make_batch_bar

    exts = tuple(e.strip().lower().lstrip(".") for e in formats.split(",") if e.strip())
    if not exts:
        raise click.BadParameter("give at least one format", param_hint="--to")
    if len(set(exts)) != len(exts):
        raise click.BadParameter(f"{formats!r} names a format twice", param_hint="--to")
    from .methods import SPLITTABLE

    if split > 1 and method not in SPLITTABLE:
        raise click.UsageError(
            f"--split applies to --method {'/'.join(SPLITTABLE)} only: {method} couples all vertices"
        )
    settings = Settings(
        **_bake_settings(method, color, channel, weld, up, meters_per_unit, fields, time_code, overlay, given, ground)
    )
    if split > 1 and weld:
        raise click.UsageError("--split bakes vertex ranges; a welded mesh is baked whole (drop --weld or --split)")
    if emit_commands and (scheduler or workers or split > 1):
        raise click.UsageError("--emit-commands bakes nothing: --scheduler, --workers and --split do not apply")
    if emit_commands:
        for line in emit(paths, outdir, formats=exts, settings=settings, force=force):
            click.echo(line)
        return

    bar = make_batch_bar(quiet)

    def on_failure(record):  # below the bar, which redraws on the next line
        click.echo(("" if isinstance(bar, NullBatchBar) else "\n") + f"failed: {record['error']}", err=True)

    try:
        result = run_batch(
            paths,
            outdir,
            formats=exts,
            settings=settings,
            workers=workers,
            scheduler=scheduler,
            split=split,
            retries=retries,
            force=force,
            bar=bar,
            on_failure=on_failure,
        )
    except KeyboardInterrupt:
        click.echo(f"batch interrupted: {outdir / 'manifest.json'} records what finished; run it again to resume", err=True)
        sys.exit(130)
    if not quiet or result.failed:
        click.echo(result.summary(), err=True)
    if result.failed:
        sys.exit(1)


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
    from . import precompile
    from .pipeline import fit_field_file
    from .progress import make_progress

    # a cold cache: the texel fit's kernel compiles in a helper process, on another core
    with compile_notice(quiet), precompile.enabled():
        report = fit_field_file(occluder, output, progress=make_progress(quiet), **options)
    if not quiet:
        click.echo(report.summary(), err=True)


@main.command()
@click.argument("reference", type=click.Path(path_type=Path))
@click.argument("candidate", type=click.Path(path_type=Path))
@click.option(
    "--threshold", type=NumberRange(min=0), default=0.05, show_default=True, help="Report the share above this |error|."
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
    """Error report of CANDIDATE against REFERENCE (bakes of one mesh: PLY, USD, glTF or .npy).

    Prints RMSE, MAE, mean error, max and p50/p95/p99 of |error| (error = candidate -
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
    "--reference-rays",
    type=click.IntRange(min=16),
    default=4096,
    show_default=True,
    help="Rays of the Embree reference (lit scenes: also its samples per area light, with 4x as many paths).",
)
@click.option("--repeats", type=click.IntRange(min=1), default=3, show_default=True, help="Time each setting this often (best).")
@click.option("--no-plot", is_flag=True, help="Skip pareto.png and pareto_irradiance.png (no matplotlib needed).")
@click.option(
    "--no-fields",
    is_flag=True,
    help="Skip the AO-field rows (MESH as one rigid occluder over a ground grid; skip them for scenes with a floor).",
)
@click.option(
    "--up", type=click.Choice(["Y", "Z"]), default=None, help="Up axis for the field rows' ground [default: the file's, else Y]."
)
@LIGHT_OPTIONS[1]
@LIGHT_OPTIONS[2]
@common_options
def sweep(mesh, out_dir, reference_rays, repeats, no_plot, no_fields, up, lights, no_scene_lights, seed, threads, quiet):
    """What accuracy costs in time: bake MESH over a grid of methods and settings.

    Each setting is timed and compared with a high-ray Embree reference (cached in
    OUTPUT). Rows marked "(ground)" use MESH as a rigid occluder on a ground grid and
    score AO fields on the ground. Writes sweep.csv, sweep.json and pareto.png (error
    against seconds, log-log, Pareto fronts marked) into OUTPUT and prints the table.

    A lit scene (its lights or emitters, or --light) also gets irradiance rows, each
    method's light alone timed and scored by relative RMSE against Embree's irradiance
    at --reference-rays samples and 4x as many paths (cached too): marked "irradiance"
    in the CSV and JSON, plotted in pareto_irradiance.png.
    """
    from .pipeline import sweep_file
    from .progress import make_progress
    from .tools.plot import pyplot
    from .tools.sweep import to_markdown

    plot = not no_plot and pyplot(required=False) is not None
    if not no_plot and not plot:
        click.echo("Note: matplotlib is not installed; writing sweep.csv and sweep.json, skipping pareto.png", err=True)

    def on_row(row):
        if not quiet:
            what = "RMSE" if row.quantity == "ao" else "rel. RMSE of irradiance"
            click.echo(f"  {row.method:8s} {row.label:24s} {row.seconds:8.3f} s  {what} {row.rmse:.4f}", err=True)

    with compile_notice(quiet):
        rows = sweep_file(
            mesh,
            out_dir,
            reference_rays=reference_rays,
            seed=seed,
            threads=threads,
            repeats=repeats,
            fields=not no_fields,
            up=up,
            plot=plot,
            progress=make_progress(quiet),
            on_row=on_row,
            lights=lights,
            scene_lights=not no_scene_lights,
        )
    if not no_plot and not plot and any(r.quantity != "ao" for r in rows):
        click.echo("Note: matplotlib is not installed; skipping pareto_irradiance.png too", err=True)
    click.echo(to_markdown(rows))


@main.command()
@click.argument("bake", type=click.Path(path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(path_type=Path), help="Output .png.")
@click.option("--view", type=click.Choice(list(VIEWS)), default="iso", show_default=True, help="Camera direction.")
@click.option(
    "--azimuth",
    type=NumberRange(),
    default=None,
    help="Degrees about the up axis, overriding --view's "
    f"[default: the view's: {', '.join(f'{v} {a:g}' for v, (a, _) in VIEWS.items())}].",
)
@click.option(
    "--elevation",
    type=NumberRange(-90, 90),
    default=None,
    help="Degrees above the horizon, overriding --view's "
    f"[default: the view's: {', '.join(f'{v} {e:g}' for v, (_, e) in VIEWS.items())}].",
)
@click.option("--size", type=click.IntRange(16, 8192), default=640, show_default=True, help="Image side in pixels.")
@click.option("--up", type=click.Choice(["Y", "Z"]), default=None, help="Up axis [default: the file's, else Y].")
@click.option(
    "--show",
    type=click.Choice(["ao", "color"]),
    default="ao",
    show_default=True,
    help="ao: the AO as grey; color: the vertex colours (--color's, the lit colour of a lit bake).",
)
def preview(bake, output, view, azimuth, elevation, size, up, show):
    """Render BAKE (a PLY, USD or glTF file with `ao`) to a PNG: AO as grey, white = open,
    or with --show color its vertex colours."""
    from .pipeline import preview_file

    with compile_notice(False):
        preview_file(bake, output, size=size, up=up, view=view, azimuth=azimuth, elevation=elevation, show=show)


@main.command("warm-up")
@click.option("--quiet", "-q", is_flag=True, help="No progress bar or summary on stderr.")
def warm_up_command(quiet):
    """Compile the kernels every command needs, once, so that later runs start at once.

    numba compiles aobake's kernels on their first use and caches them on disk (a
    minute or two on a new install, then never again). This bakes a tiny built-in scene
    with every method, fits and applies a small field and renders a preview, nothing
    written outside a temporary directory. `make bake` runs it first.
    """
    from .pipeline import warm_up
    from .progress import make_progress

    with compile_notice(quiet):
        report = warm_up(progress=make_progress(quiet))
    if not quiet:
        click.echo(report.summary(), err=True)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
