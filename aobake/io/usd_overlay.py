"""USD outputs that keep the user's USD scene: an overlay layer over the source, a
flattened full copy, and a self-contained ``.usdz`` package.

The overlay is a new layer whose only sublayer is the source (a path relative to the
overlay, so both files can move together) and whose only prims are ``over`` specs at
the source's own prim paths, each with ``primvars:ao`` (``vertex``) and, with ``color``,
``primvars:displayColor``. Nothing of the source is copied; opening the overlay shows
the source scene with AO. Meshes under native instances get their own AO (each
instance sees a different neighbourhood), so the overlay turns those instances into
ordinary prims with ``instanceable = false``; the source file keeps its instancing.

The full copy is the composed overlay flattened into one layer (hierarchy, prim paths,
xformOps, primvars, materials kept); ``.usdz`` packs that copy (or, for a non-USD
input, aobake's own stage) with its textures. Computes no AO; imports pxr inside the
functions only.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from ..errors import FormatError, InputError, OutputError
from .common import atomic_write, check_ao, check_attributes, check_display

#: Stage metadata the overlay copies from the source's root layer: a stage takes them
#: from its root layer only, and a sublayer whose timeCodesPerSecond differs from the
#: root's is rescaled in time.
_STAGE_METADATA = (
    "defaultPrim",
    "startTimeCode",
    "endTimeCode",
    "timeCodesPerSecond",
    "framesPerSecond",
    "kilogramsPerUnit",
)


#: MS-DOS date (2000-01-01) and time (00:00) written into every package entry, in
#: place of the clock time the packager records, so the same inputs give the same bytes.
_ZIP_DATE = (2000 - 1980) << 9 | 1 << 5 | 1
_ZIP_TIME = 0


def usd_source(surface) -> Path | None:
    """The USD file a surface was read from (its prims can be overlaid), else None."""
    path = surface.metadata.get("path")
    if surface.metadata.get("format") != "USD" or not path:
        return None
    if any(part.prim_path is None for part in surface.parts):
        return None
    return Path(path)


def write_usd_overlay(
    path: str | Path,
    surface,
    ao,
    *,
    color: bool = False,
    up_axis: str = "Y",
    meters_per_unit: float = 1.0,
    custom_data: Mapping | None = None,
    channel: str | None = None,
    attributes: Mapping | None = None,
    display=None,
) -> None:
    """Write a layer that sublayers the surface's USD source and adds ``primvars:ao``.

    Parameters
    ----------
    path : str or Path
        ``.usda``, ``.usdc`` or ``.usd``; written atomically, never the source itself.
    surface : aobake.mesh.Surface
        Read from a USD file by :func:`aobake.io.load_mesh` (its parts carry the prim
        paths and ``metadata["path"]`` the source).
    ao : (n,) float in [0, 1]
        One value per surface vertex.
    color : bool
        Also author ``primvars:displayColor`` (vertex, linear grey = ao).
    up_axis, meters_per_unit
        Authored on the overlay (a stage reads them from its root layer).
    custom_data : mapping, optional
        Recorded as ``customLayerData["aobake"]``, with ``source`` set to the sublayer
        path and ``time`` to the time code read (``"default"`` for USD's default time).
    channel : {"R", "G", "B", "A"}, optional
        Write ``ao`` (linear) into this channel of each mesh's own colours:
        ``displayColor`` for R, G, B (the other two kept bit-identical), a vertex
        ``displayOpacity`` for A (see :func:`check_channel`).
    attributes : mapping of str to array, optional
        Extra per-vertex values, each a vertex primvar of its name
        (:func:`aobake.io.usd.primvar_value`).
    display : (n, 3) float in [0, 1], optional
        Linear colours ``color`` authors as ``displayColor`` instead of grey ``ao``.

    Raises
    ------
    OutputError
        The surface was not read from USD, ``path`` is the source, the source changed
        since it was read (a prim is gone or has another point count), or writing fails.
    NumericalError
        Bad ``ao`` (checked before anything is opened).
    """
    path = Path(path)
    source = _checked_source(path, surface)
    ao32 = check_ao(ao, n_vertices=surface.n_vertices, where=path.name)
    extras = _extras(attributes, display, surface, path)
    relative = _relative(source, path.resolve().parent)
    layer = _overlay_layer(
        source, relative, surface, ao32, color, up_axis, meters_per_unit, custom_data, path, channel, extras
    )
    _export(layer, path)


def write_usd_copy(
    path: str | Path,
    surface,
    ao,
    *,
    color: bool = False,
    up_axis: str = "Y",
    meters_per_unit: float = 1.0,
    custom_data: Mapping | None = None,
    channel: str | None = None,
    attributes: Mapping | None = None,
    display=None,
) -> None:
    """Write the surface's USD source flattened into one layer, with ``primvars:ao`` added.

    Same parameters as :func:`write_usd_overlay`; the result is the composed overlay
    flattened (``Usd.Stage.Flatten``): every prim at its source path with its xformOps,
    primvars, materials and bindings; asset paths made absolute by the flattening.
    ``customLayerData["aobake"]["source"]`` is the source's path relative to ``path``.
    """
    path = Path(path)
    source = _checked_source(path, surface)
    ao32 = check_ao(ao, n_vertices=surface.n_vertices, where=path.name)
    extras = _extras(attributes, display, surface, path)
    flat = _flattened(
        source, path, surface, ao32, color, up_axis, meters_per_unit, custom_data, channel, extras
    )
    _export(flat, path)


def write_usdz(
    path: str | Path,
    surface,
    ao,
    *,
    color: bool = False,
    up_axis: str = "Y",
    meters_per_unit: float = 1.0,
    custom_data: Mapping | None = None,
    channel: str | None = None,
    attributes: Mapping | None = None,
    display=None,
) -> None:
    """Write a self-contained ``.usdz`` package: for a USD input its flattened copy with
    ``primvars:ao`` (:func:`write_usd_copy`) and the textures it uses, else aobake's own
    stage (:func:`aobake.io.usd.write_usd`). Same parameters as :func:`write_usd_copy`."""
    from pxr import Sdf, UsdUtils

    from .usd import write_usd

    path = Path(path)
    source = usd_source(surface)
    ao32 = check_ao(ao, n_vertices=surface.n_vertices, where=path.name)
    extras = _extras(attributes, display, surface, path)
    name = f"{Path(str(surface.source)).stem or 'scene'}.usdc"
    with atomic_write(path) as tmp, tempfile.TemporaryDirectory(dir=tmp.parent) as work:
        inner = Path(work) / name
        if source is None:
            if channel is not None:
                raise FormatError(
                    f"{path.name}: --channel is not written to USD from a "
                    f"{surface.metadata.get('format', 'non-USD')} input; it writes into a "
                    "USD input's own displayColor"
                )
            write_usd(
                inner,
                surface,
                ao32,
                color=color,
                up_axis=up_axis,
                meters_per_unit=meters_per_unit,
                custom_data=custom_data,
                attributes=attributes,
                display=display,
            )
        else:
            _checked_source(path, surface)
            flat = _flattened(
                source, path, surface, ao32, color, up_axis, meters_per_unit, custom_data, channel, extras
            )
            _export(flat, inner)
            del flat
        try:
            ok = UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(inner)), str(tmp), name)
        except Exception as exc:  # Tf.ErrorException
            raise OutputError(f"{path.name}: USD cannot write the package ({exc})") from None
        if not ok:
            raise OutputError(f"{path.name}: USD failed to write the package")
        _fix_zip_times(tmp)


# -- shared ------------------------------------------------------------------------------


def _checked_source(path: Path, surface) -> Path:
    source = usd_source(surface)
    if source is None:
        raise OutputError(
            f"{path.name}: an overlay or full copy needs a surface read from a USD file"
        )
    if path.resolve() == source.resolve():
        raise OutputError(
            f"{path.name}: is the USD source itself; write the overlay to a new file"
        )
    return source


def _relative(source: Path, directory: Path) -> str:
    """``source`` relative to ``directory`` with forward slashes (absolute across drives)."""
    try:
        return Path(os.path.relpath(source, directory)).as_posix()
    except ValueError:
        return source.as_posix()


def _extras(attributes, display, surface, path: Path):
    """Checked extra attributes and display colours: ``(dict, array or None)``."""
    n = surface.n_vertices
    return check_attributes(attributes, n, path.name), check_display(display, n, path.name)


def _flattened(
    source, path, surface, ao32, color, up_axis, meters_per_unit, custom_data, channel, extras=({}, None)
):
    """The overlay (sublayering the absolute source) composed and flattened to one layer."""
    from pxr import Usd

    layer = _overlay_layer(
        source, str(source), surface, ao32, color, up_axis, meters_per_unit, custom_data, path, channel, extras
    )
    stage = Usd.Stage.Open(layer)
    flat = stage.Flatten()
    del stage
    data = dict(flat.customLayerData)
    data["aobake"] = dict(data.get("aobake", {}), source=_relative(source, path.resolve().parent))
    flat.customLayerData = data
    flat.documentation = ""
    return flat


def _overlay_layer(
    source, sublayer, surface, ao32, color, up_axis, meters_per_unit, custom_data, out, channel=None,
    extras=({}, None),
):  # fmt: skip
    """An anonymous layer: ``sublayer`` below, ``over`` prims with the primvars above."""
    from pxr import Sdf, Usd, UsdGeom, Vt

    from .usd import _clean_custom_data, _usd_value, primvar_value

    attributes, display = extras

    data = _clean_custom_data(custom_data)
    time = surface.metadata.get("time")
    code = Usd.TimeCode.Default() if time is None else Usd.TimeCode(time)
    data.update(source=sublayer, time="default" if time is None else float(time))
    stage = Usd.Stage.Open(str(source))
    if stage is None:
        raise OutputError(f"{out.name}: the USD source {source.name} no longer opens")
    layer = Sdf.Layer.CreateAnonymous(".usda")
    layer.subLayerPaths.append(sublayer)
    root = stage.GetRootLayer().pseudoRoot
    for key in _STAGE_METADATA:
        if root.HasInfo(key):
            layer.pseudoRoot.SetInfo(key, root.GetInfo(key))
    layer.pseudoRoot.SetInfo(UsdGeom.Tokens.upAxis, UsdGeom.Tokens.y if up_axis == "Y" else UsdGeom.Tokens.z)
    layer.pseudoRoot.SetInfo(UsdGeom.Tokens.metersPerUnit, float(meters_per_unit))
    layer.customLayerData = {"aobake": data}
    with Sdf.ChangeBlock():
        for part in surface.parts:
            prim = stage.GetPrimAtPath(part.prim_path)
            points = _usd_value(UsdGeom.Mesh(prim).GetPointsAttr(), code, ()) if prim else ()
            if not prim or not prim.IsA(UsdGeom.Mesh) or len(points) != part.n_vertices:
                raise OutputError(
                    f"{out.name}: {source.name} changed since it was read "
                    f"({part.prim_path} is not a mesh of {part.n_vertices} points)"
                )
            values = np.ascontiguousarray(ao32[part.vertex_start : part.vertex_stop])
            _deinstance(layer, prim, Sdf)
            spec = Sdf.CreatePrimInLayer(layer, prim.GetPath())
            _author_primvar(
                spec, prim, "ao", Sdf.ValueTypeNames.FloatArray, Vt.FloatArray.FromNumpy(values)
            )
            s = slice(part.vertex_start, part.vertex_stop)
            for name, (kind, extra) in attributes.items():
                _author_primvar(spec, prim, name, *primvar_value(kind, extra[s]))
            if channel is not None:
                packed = _channel_primvar(prim, code, values, channel)
                if isinstance(packed, str):
                    raise InputError(surface.source, f"--channel {channel}: {packed}")
                _author_primvar(spec, prim, *packed)
            if color:
                shown = np.repeat(values[:, None], 3, axis=1) if display is None else display[s]
                grey = np.ascontiguousarray(shown, dtype=np.float32)
                _author_primvar(
                    spec,
                    prim,
                    "displayColor",
                    Sdf.ValueTypeNames.Color3fArray,
                    Vt.Vec3fArray.FromNumpy(grey),
                )
    del stage
    return layer


def check_channel(surface, channel: str) -> None:
    """Refuse ``--channel`` before baking when a baked mesh of the USD source has no
    colours to write into (no authored ``primvars:displayColor``) or colours of another
    shape than one colour per element (``elementSize`` != 1).

    Raises
    ------
    InputError
        ``--channel C: /World/floor has no primvars:displayColor to write into``.
    """
    from pxr import Usd

    source = usd_source(surface)
    time = surface.metadata.get("time")
    code = Usd.TimeCode.Default() if time is None else Usd.TimeCode(time)
    stage = Usd.Stage.Open(str(source))
    for part in surface.parts:
        prim = stage.GetPrimAtPath(part.prim_path)
        if not prim:
            continue  # the writer reports a source changed since it was read
        packed = _channel_primvar(prim, code, np.ones(part.n_vertices, dtype=np.float32), channel)
        if isinstance(packed, str):
            raise InputError(surface.source, f"--channel {channel}: {packed}")


def _channel_primvar(prim, code, ao: np.ndarray, channel: str):
    """What ``--channel`` writes on one mesh, ``(name, type, value, interpolation)``, or
    why it cannot (a str).

    R, G, B: ``displayColor`` with ``ao`` in that component and the others the source's
    (flattened, float32, so bit-identical). Constant and vertex colours become vertex
    colours; uniform and faceVarying colours become faceVarying, each corner taking the
    ``ao`` of its vertex, so per-face colours survive. A: ``displayOpacity`` = ``ao`` per
    vertex (the colours themselves are left as they are).
    """
    from pxr import Sdf, UsdGeom, Vt

    from .usd import _usd_value

    where = str(prim.GetPath())
    colour = UsdGeom.PrimvarsAPI(prim).GetPrimvar("displayColor")
    if not colour or not colour.HasAuthoredValue():
        return f"{where} has no primvars:displayColor to write into"
    if colour.GetElementSize() != 1:
        return f"{where}: displayColor has elementSize {colour.GetElementSize()}; expected 1"
    if channel == "A":
        return "displayOpacity", Sdf.ValueTypeNames.FloatArray, Vt.FloatArray.FromNumpy(ao), "vertex"
    values = np.asarray(colour.ComputeFlattened(code), dtype=np.float32).reshape(-1, 3)
    interpolation = colour.GetInterpolation()
    tokens = UsdGeom.Tokens
    per_corner = interpolation in (tokens.uniform, tokens.faceVarying)
    if per_corner:
        mesh = UsdGeom.Mesh(prim)
        counts = np.asarray(_usd_value(mesh.GetFaceVertexCountsAttr(), code, ()), dtype=np.int64)
        indices = np.asarray(_usd_value(mesh.GetFaceVertexIndicesAttr(), code, ()), dtype=np.int64)
        expected = len(counts) if interpolation == tokens.uniform else len(indices)
        target = ao[indices] if len(indices) and indices.max() < len(ao) else None
    else:
        expected = 1 if interpolation == tokens.constant else len(ao)
        target = ao
    if len(values) != expected or target is None:
        return f"{where}: displayColor has {len(values)} {interpolation} values; expected {expected}"
    if interpolation == tokens.uniform:
        values = np.repeat(values, counts, axis=0)
    elif interpolation == tokens.constant:
        values = np.repeat(values, len(ao), axis=0)
    values = np.array(values, dtype=np.float32)
    values[:, "RGB".index(channel)] = target
    return (
        "displayColor",
        Sdf.ValueTypeNames.Color3fArray,
        Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(values)),
        tokens.faceVarying if per_corner else tokens.vertex,
    )


def _deinstance(layer, prim, Sdf) -> None:
    """``instanceable = false`` on every instance above ``prim`` (outermost first), so
    opinions at ``prim``'s path compose."""
    instances = []
    parent = prim.GetParent()
    while parent and not parent.IsPseudoRoot():
        if parent.IsInstance():
            instances.append(parent.GetPath())
        parent = parent.GetParent()
    for instance in reversed(instances):
        Sdf.CreatePrimInLayer(layer, instance).SetInfo("instanceable", False)


def _author_primvar(spec, prim, name: str, value_type, value, interpolation="vertex") -> None:
    """``primvars:NAME`` with a (by default vertex) value on ``spec``; the source's
    indices for it, if any, are blocked (they would re-index the new values)."""
    from pxr import Sdf, UsdGeom

    attr_name = f"primvars:{name}"
    attr = spec.attributes.get(attr_name) or Sdf.AttributeSpec(spec, attr_name, value_type)
    attr.default = value
    attr.SetInfo("interpolation", interpolation)
    source_primvar = UsdGeom.PrimvarsAPI(prim).GetPrimvar(name)
    if source_primvar and source_primvar.GetElementSize() != 1:
        attr.SetInfo("elementSize", 1)
    if source_primvar and source_primvar.IsIndexed():
        indices_name = f"{attr_name}:indices"
        indices = spec.attributes.get(indices_name) or Sdf.AttributeSpec(
            spec, indices_name, Sdf.ValueTypeNames.IntArray
        )
        indices.default = Sdf.ValueBlock()


def _fix_zip_times(path: Path) -> None:
    """Overwrite the date and time fields of every zip entry in place (same sizes, so the
    package's 64-byte data alignment and its CRCs are untouched)."""
    import struct
    import zipfile

    with zipfile.ZipFile(path) as archive:
        infos = archive.infolist()
        directory = archive.start_dir
    data = bytearray(path.read_bytes())
    stamp = struct.pack("<HH", _ZIP_TIME, _ZIP_DATE)
    for info in infos:  # local file headers: signature, version, flags, method, time, date
        if data[info.header_offset : info.header_offset + 4] != b"PK\x03\x04":
            raise OutputError(f"{path.name}: unexpected package layout")
        data[info.header_offset + 10 : info.header_offset + 14] = stamp
    offset = directory
    for _ in infos:  # central directory: signature, made by, needed, flags, method, time, date
        if data[offset : offset + 4] != b"PK\x01\x02":
            raise OutputError(f"{path.name}: unexpected package layout")
        data[offset + 12 : offset + 16] = stamp
        name, extra, comment = struct.unpack("<HHH", data[offset + 28 : offset + 34])
        offset += 46 + name + extra + comment
    path.write_bytes(bytes(data))


def _export(layer, path: Path) -> None:
    """Save ``layer`` (anonymous, not registered under ``path``) to ``path`` atomically."""
    try:
        with atomic_write(path) as tmp:
            if not layer.Export(str(tmp)):
                raise OutputError(f"{path.name}: USD failed to save the layer")
    except OSError as exc:
        raise OutputError(f"{path.name}: cannot write ({exc.strerror or exc})") from exc
    except OutputError:
        raise
    except Exception as exc:  # Tf.ErrorException
        raise OutputError(f"{path.name}: USD cannot write the layer ({exc})") from None
