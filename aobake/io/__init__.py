"""Mesh files in and bake files out, by suffix: one module per format (reading and
writing together), atomic writes and the checks run before any write.

Computes no AO. Importing it loads numpy only: trimesh and pxr are imported inside the
functions that need them.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from ..errors import FormatError, InputError
from ..mesh import Surface, assemble_surface
from . import gltf, obj, ply, trimesh_formats, usd, usd_overlay
from .common import (
    BAKE_SUFFIXES,
    atomic_write,
    check_ao,
    check_input_file,
    check_output_dir,
    output_kind,
    short_reason,
)
from .ply import read_ao_ply, write_kept_ply, write_ply
from .usd import read_ao_usd, write_usd

__all__ = [
    "BAKE_SUFFIXES",
    "INPUT_FORMATS",
    "READ_SUFFIXES",
    "atomic_write",
    "check_ao",
    "check_input_file",
    "check_outputs",
    "check_output_dir",
    "load_mesh",
    "output_kind",
    "read_ao_ply",
    "read_ao_usd",
    "read_bake",
    "read_colours",
    "usd_output_mode",
    "write_bake",
    "write_ply",
    "write_usd",
]

#: Input suffixes and the format name used in messages.
INPUT_FORMATS = {
    ".ply": "PLY",
    ".obj": "OBJ",
    ".stl": "STL",
    ".off": "OFF",
    ".glb": "glTF",
    ".gltf": "glTF",
    ".usd": "USD",
    ".usda": "USD",
    ".usdc": "USD",
    ".usdz": "USD",
}


def load_mesh(path: str | Path, *, time: float | None = None, prepare=None) -> Surface:
    """Read a mesh file into a :class:`Surface`, keeping its vertices exactly.

    Vertex count and order are the file's: duplicate, unreferenced and degenerate data
    survive (trimesh, used for STL, OFF and glTF, is called with ``process=False``, which
    does not merge vertices). A file holding several meshes
    (glTF nodes, OBJ objects, USD ``Mesh`` prims) becomes one surface whose parts are
    the meshes in file order, with world transforms applied; point clouds and curves are
    ignored.

    Parameters
    ----------
    path : str or Path
        A ``.ply``, ``.obj``, ``.stl``, ``.off``, ``.glb``, ``.gltf``, ``.usd``,
        ``.usda``, ``.usdc`` or ``.usdz`` file.
    time : float, optional
        USD only: the time code to read points and transforms at (default: USD's
        default time; a scene whose geometry has only time samples is read at its
        earliest sample, see :func:`aobake.io.usd.read_parts`). ``metadata["time"]``
        says which time was read.
    prepare : callable, optional
        ``prepare(positions, faces)``, called with the surface's arrays once they are
        read and checked, before its normals are computed
        (:func:`aobake.mesh.assemble_surface`).

    Returns
    -------
    Surface
        ``positions`` (n, 3) float64 in world space, ``faces`` (m, 3) int64 (polygons
        fan-triangulated), ``normals`` (n, 3) float64: the file's vertex normals
        (PLY ``nx ny nz``, OBJ ``vn``, glTF ``NORMAL``, USD ``normals`` with vertex or
        varying interpolation) transformed by the inverse transpose of the world
        transform, else angle-weighted face normals; zero rows where no normal exists.

    Raises
    ------
    InputError
        Missing file, directory, FIFO or device, unsupported suffix, unreadable or malformed data, empty
        mesh, no faces, NaN/inf coordinates, or indices out of range. The message is one
        line starting with the file name; foreign exceptions are chained.

    Notes
    -----
    Transforms that mirror (negative determinant) and USD ``leftHanded`` meshes get
    their winding reversed, so faces stay counter-clockwise around their normal. PLY and
    OBJ are read by aobake (:mod:`aobake.io.ply`, :mod:`aobake.io.obj`; trimesh misreads
    some of both), STL, OFF and glTF by trimesh (:mod:`aobake.io.trimesh_formats`), USD
    by pxr (:mod:`aobake.io.usd`).
    """
    path = Path(path)
    fmt = INPUT_FORMATS.get(path.suffix.lower())
    check_input_file(path)
    if fmt is None:
        supported = ", ".join(sorted(INPUT_FORMATS))
        raise InputError(
            path, f"unsupported input suffix {path.suffix or '(none)'!r}; use one of {supported}"
        )
    if time is not None and fmt != "USD":
        raise InputError(path, f"a time was given but {fmt} files have no time samples (USD only)")
    metadata: dict = {"format": fmt}
    try:
        if fmt == "USD":
            raw = usd.read_parts(path, metadata, time)
        else:
            data = path.read_bytes()
            if fmt == "OBJ":
                raw = obj.read_parts(path, data)
            elif fmt == "PLY":
                raw = ply.read_parts(path, data, metadata)
            else:
                raw = trimesh_formats.read_parts(path, data, fmt, metadata)
    except InputError:
        raise
    except OSError as exc:
        raise InputError(path, f"cannot read file: {exc.strerror or short_reason(exc)}") from exc
    except Exception as exc:  # any loader failure becomes a one-line InputError
        raise InputError(path, f"cannot read as {fmt}: {short_reason(exc)}") from exc
    return assemble_surface(raw, path, metadata, prepare)


#: Suffixes :func:`read_bake` understands, and the reader family for each.
READ_SUFFIXES = {
    ".ply": "ply",
    ".usd": "usd",
    ".usda": "usd",
    ".usdc": "usd",
    ".usdz": "usd",
    ".glb": "gltf",
    ".gltf": "gltf",
    ".npy": "npy",
}


def write_bake(
    path: str | Path,
    surface,
    ao,
    *,
    color: bool = False,
    up_axis: str = "Y",
    meters_per_unit: float = 1.0,
    custom_data: Mapping[str, str | float | int | bool] | None = None,
    channel: str | None = None,
    overlay: bool | None = None,
    attributes: Mapping[str, np.ndarray] | None = None,
    display: np.ndarray | None = None,
) -> None:
    """Write a baked surface to ``path``, choosing PLY, USD or glTF from its suffix.

    glTF (``.gltf``/``.glb``): a glTF input's own document with ``_AO`` per primitive,
    else a new document of the parts (:func:`aobake.io.gltf.write_gltf`).

    PLY: a PLY input is written back whole with ``ao`` added
    (:func:`aobake.io.ply.write_kept_ply`: every element and property kept); other
    inputs as the whole surface concatenated (positions, triangles, normals, ``ao``).
    ``custom_data`` becomes ``comment aobake <key>=<value>`` header lines, and
    ``up_axis`` and ``meters_per_unit`` are recorded the same way (PLY has no field for
    them; :func:`load_mesh` reads them back). USD gets one mesh per part with its
    original polygons (see :func:`aobake.io.usd.write_usd`), except for a surface read
    from USD: then an overlay layer over the source (the default) or, with
    ``overlay=False``, the source flattened with ``ao`` added (see
    :mod:`aobake.io.usd_overlay`). ``.usdz`` is always a flattened, self-contained package.

    Parameters
    ----------
    path : str or Path
        ``.ply``, ``.usda``, ``.usdc``, ``.usd``, ``.usdz``, ``.gltf`` or ``.glb``; written atomically.
    surface : aobake.mesh.Surface
        ``positions (n, 3) float64``, ``faces (m, 3) int64``, ``normals (n, 3) float64``
        and ``parts``.
    ao : (n,) float in [0, 1]
        Accessibility 1 - A (1 = fully open), one value per surface vertex.
    color : bool
        Also write ``ao`` as grey vertex colours (sRGB bytes in PLY, linear elsewhere:
        :mod:`aobake.io.color`).
    up_axis : {"Y", "Z"}
        USD stage ``upAxis``, recorded in PLY comments.
    meters_per_unit : float
        USD stage ``metersPerUnit``.
    custom_data : mapping of str to str, float, int or bool, optional
        Provenance (method, parameters, seed, version).
    channel : {"R", "G", "B", "A"}, optional
        Write ``ao`` (linear) into this channel of the input's own vertex colours,
        keeping the other channels; an input without colours is an InputError.
    overlay : bool, optional
        USD outputs of a USD input: True or None (default) writes an overlay, False a
        full flattened copy. True for another input is an error (see
        :func:`usd_output_mode`).
    attributes : mapping of str to array, optional
        Extra per-vertex values beside ``ao``, one row per surface vertex, written to
        every output (:func:`aobake.io.common.check_attributes`). Their kind comes from
        the name: ``bentNormal`` is a normal ``(n, 3)``, names starting ``irradiance``
        linear colours ``(n, 3)``, any other name a float ``(n,)``. PLY: float32
        properties ``name_x name_y name_z`` / ``name_r name_g name_b`` / ``name``; USD:
        vertex primvars ``normal3f[]`` / ``color3f[]`` / ``float[]``; glTF: float
        attributes ``_NAME`` (upper case) VEC3 / VEC3 / SCALAR.
    display : (n, 3) float in [0, 1], optional
        Linear RGB that ``color`` writes instead of grey ``ao`` (sRGB bytes in PLY,
        linear ``displayColor``/``COLOR_0``); ignored without ``color``.

    Raises
    ------
    FormatError
        Unsupported suffix, or ``overlay`` that does not apply (checked first).
    NumericalError
        ``ao`` is not ``(n,)`` for the surface's ``n`` vertices, non-finite, or
        outside [0, 1]; an attribute or ``display`` of the wrong shape, non-finite or
        out of range (checked by the writer before anything is opened).
    InputError, OutputError, ValueError
        From the writer (bad topology, unwritable directory, bad options).
    """
    kind = output_kind(path)
    if kind == "gltf":
        gltf.write_gltf(
            path,
            surface,
            ao,
            color=color,
            channel=channel,
            up_axis=up_axis,
            meters_per_unit=meters_per_unit,
            custom_data=None if custom_data is None else dict(custom_data),
            attributes=attributes,
            display=display,
        )
        return
    if kind == "ply":
        comments = [] if custom_data is None else [f"aobake {k}={v}" for k, v in dict(custom_data).items()]
        comments += [f"aobake up_axis={up_axis}", f"aobake meters_per_unit={meters_per_unit:g}"]
        kept = surface.metadata.get("ply")
        if kept is not None and kept.data.elements["vertex"].count == surface.n_vertices:
            write_kept_ply(path, kept, ao, color=color, channel=channel, comments=comments,
                           source=surface.source, attributes=attributes, display=display)  # fmt: skip
            return
        if channel is not None:
            raise InputError(surface.source, f"--channel {channel}: the mesh has no vertex colours to write into")
        write_ply(
            path,
            surface.positions,
            surface.faces,
            ao,
            normals=surface.normals,
            color=color,
            comments=comments,
            attributes=attributes,
            display=display,
        )
    else:
        mode = usd_output_mode(path, usd_overlay.usd_source(surface) is not None, overlay)
        if channel is not None and mode == "usd":
            raise FormatError(_usd_channel_refusal(path, surface))
        writer = {
            "usd": write_usd,
            "overlay": usd_overlay.write_usd_overlay,
            "copy": usd_overlay.write_usd_copy,
            "usdz": usd_overlay.write_usdz,
        }[mode]
        extra = {} if channel is None else {"channel": channel}
        if attributes:
            extra["attributes"] = attributes
        if display is not None:
            extra["display"] = display
        writer(
            path,
            surface,
            ao,
            color=color,
            up_axis=up_axis,
            meters_per_unit=meters_per_unit,
            custom_data=custom_data,
            **extra,
        )


def _usd_channel_refusal(path, surface) -> str:
    return (
        f"{Path(path).name}: --channel is not written to USD from a "
        f"{surface.metadata.get('format', 'non-USD')} input; it writes into a USD input's own "
        "displayColor (use PLY or glTF output)"
    )


def check_outputs(surface: Surface, outputs, channel: str | None = None) -> None:
    """Refuse, before baking, what the writers would refuse after it: a glTF input whose
    meshes cannot be found in its document again (glTF output) or whose image files are
    missing (GLB output embeds them), and ``--channel`` where an output cannot take it
    (USD output of a non-USD input, an input without vertex colours: PLY ``red green
    blue``, glTF ``COLOR_0``, USD ``displayColor``)."""
    kinds = {output_kind(path) for path in outputs}
    if "gltf" in kinds and surface.metadata.get("gltf_path"):
        doc = gltf.read_document(surface.metadata["gltf_path"])
        gltf.match_parts(doc, surface, warn=False)
        if any(Path(path).suffix.lower() == ".glb" for path in outputs):
            gltf.check_images(doc)
    if channel is None:
        return
    for path in outputs:
        kind = output_kind(path)
        if kind in ("usd", "usdz"):
            if usd_overlay.usd_source(surface) is None:
                raise FormatError(_usd_channel_refusal(path, surface))
            usd_overlay.check_channel(surface, channel)
            continue
        kept = surface.metadata.get("ply")
        if kind == "ply" and kept is not None:
            if ply.vertex_colors(kept) is None:
                raise InputError(surface.source, f"--channel {channel}: the mesh has no vertex colours (red green blue)")
        elif kind == "gltf" and surface.metadata.get("gltf_path"):
            gltf.check_channel(gltf.read_document(surface.metadata["gltf_path"]), channel)
        elif kind == "gltf" and gltf.ply_has_colors(surface):
            pass
        else:
            raise InputError(surface.source, f"--channel {channel}: the mesh has no vertex colours to write into")


def usd_output_mode(path: str | Path, usd_input: bool, overlay: bool | None = None) -> str:
    """How a USD output is written: ``"overlay"``, ``"copy"``, ``"usdz"`` or ``"usd"``
    (aobake's own stage, for non-USD inputs); ``"ply"`` or ``"gltf"`` for those.

    ``overlay`` None means the default (an overlay when input and output are both USD).
    Raises :class:`FormatError` when ``overlay=True`` cannot be honoured: the input is
    not USD, or the output is a ``.usdz`` package (self-contained by definition).
    """
    kind = output_kind(path)
    if kind in ("ply", "gltf"):
        return kind
    if overlay and kind == "usdz":
        raise FormatError(
            f"{Path(path).name}: a .usdz package is self-contained and cannot be an overlay; "
            "write the overlay as .usda, .usdc or .usd"
        )
    if overlay and not usd_input:
        raise FormatError(f"{Path(path).name}: an overlay needs a USD input to layer over")
    if kind == "usdz":
        return kind
    if not usd_input:
        return "usd"
    return "copy" if overlay is False else "overlay"


def read_bake(path: str | Path, *, n_vertices: int | None = None) -> np.ndarray:
    """Read per-vertex ``ao`` from a ``.ply``, ``.usd``/``.usda``/``.usdc``/``.usdz``,
    ``.glb``/``.gltf`` (``_AO``) or ``.npy``.

    Parameters
    ----------
    path : str or Path
        A bake written by aobake (or another tool's PLY with ``ao``/``quality``, a USD
        stage with ``primvars:ao``), or a 1-D float ``.npy`` array.
    n_vertices : int, optional
        Expected number of values (the mesh's vertex count); checked when given.

    Returns
    -------
    ao : (n,) float64
        One value per vertex, in file order (USD: all meshes in traversal order; glTF:
        ``_AO`` of the primitives in scene order).

    Raises
    ------
    InputError
        Missing or unreadable file (or not a regular file), unsupported suffix, no ``ao`` data, an ``.npy``
        that is not a 1-D float array, or a count different from ``n_vertices``.
    """
    path = Path(path)
    kind = READ_SUFFIXES.get(path.suffix.lower())
    if kind is None:
        supported = ", ".join(sorted(READ_SUFFIXES))
        raise InputError(
            path, f"unsupported AO file suffix {path.suffix or '(none)'!r}; use one of {supported}"
        )
    if kind == "ply":
        ao = read_ao_ply(path)
    elif kind == "usd":
        ao = read_ao_usd(path)
    elif kind == "gltf":
        ao = gltf.read_ao_gltf(path)
    else:
        ao = _read_npy(path)
    if n_vertices is not None and ao.shape[0] != n_vertices:
        raise InputError(
            path, f"has {ao.shape[0]} ao values but the mesh has {n_vertices} vertices"
        )
    return ao


def read_colours(path: str | Path, *, n_vertices: int | None = None) -> np.ndarray:
    """(n, 3) linear RGB vertex colours of a bake: PLY ``red green blue`` (sRGB decoded),
    USD ``displayColor``, glTF ``COLOR_0``; in :func:`read_bake`'s vertex order.

    Raises
    ------
    InputError
        Unsupported suffix, no colours, or a count different from ``n_vertices``.
    """
    path = Path(path)
    kind = READ_SUFFIXES.get(path.suffix.lower())
    if kind == "ply":
        rgb = ply.read_colours_ply(path)
    elif kind == "usd":
        rgb = usd.read_colours_usd(path)
    elif kind == "gltf":
        rgb = gltf.read_colours_gltf(path)
    else:
        raise InputError(path, f"has no vertex colours to show ({path.suffix or 'no suffix'}); use a PLY, USD or glTF bake")
    if n_vertices is not None and rgb.shape[0] != n_vertices:
        raise InputError(path, f"has {rgb.shape[0]} vertex colours but the mesh has {n_vertices} vertices")
    if not np.isfinite(rgb).all():
        raise InputError(path, "vertex colours are not finite")
    return rgb


def _read_npy(path: Path) -> np.ndarray:
    """A 1-D float ``.npy`` array as float64 (no pickles)."""
    check_input_file(path, ".npy file")
    try:
        array = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise InputError(path, "file not found") from None
    except IsADirectoryError:
        raise InputError(path, "is a directory, not an .npy file") from None
    except (OSError, ValueError, EOFError) as exc:
        raise InputError(path, f"not a readable .npy array ({exc})") from None
    if not isinstance(array, np.ndarray):
        raise InputError(path, "not a single .npy array")
    if array.ndim != 1 or not np.issubdtype(array.dtype, np.floating):
        raise InputError(
            path, f"expected a 1-D float array, got shape {array.shape} dtype {array.dtype}"
        )
    return array.astype(np.float64)
