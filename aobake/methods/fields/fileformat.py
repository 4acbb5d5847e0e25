"""The ``.npz`` format of an AO field: writing it reproducibly and atomically, reading and
checking it (:class:`~aobake.errors.InputError` naming the file on any fault)."""

from __future__ import annotations

import json
import math
import zipfile
from pathlib import Path

import numpy as np

from ...errors import InputError
from ...io.common import check_input_file
from ...kernels import field_model as _model
from .field import MODEL_CODES, AOField

#: ``field.npz`` layout version; :func:`load_field` refuses any other.
FORMAT_VERSION = 1

_SCALARS = ("radius", "r_far", "r_near", "a0", "power", "d_min", "d_max")
_STRINGS = ("model", "params", "occluder_name", "occluder_hash", "aobake_version")
_KEYS = ("format_version", "resolution", "texels", "residuals", "centre", *_SCALARS, *_STRINGS)


def save_field(f: AOField, path: str | Path) -> None:
    """Write ``f`` to ``path`` (.npz), atomically and byte-for-byte reproducibly.

    Layout (``FORMAT_VERSION`` 1): ``format_version`` and ``resolution`` (int64),
    ``texels`` (6, R+2, R+2, 7: a, b, c, r0, C_o) and ``residuals`` (6, R+2, R+2, 2)
    float32, ``centre`` (3,) and the float64 scalars ``radius``, ``r_far``,
    ``r_near``, ``a0``, ``power``, ``d_min``, ``d_max``, the strings ``model``,
    ``params`` (JSON of the fit options), ``occluder_name``, ``occluder_hash`` and
    ``aobake_version``, and for the table model ``table`` (6, R+2, R+2, M, 4) float32.
    Zip entries carry a fixed date, so the same field gives the same bytes.
    """
    from ... import __version__
    from ...io import atomic_write

    arrays = {
        "format_version": np.array(FORMAT_VERSION, dtype=np.int64),
        "resolution": np.array(f.resolution, dtype=np.int64),
        "texels": np.ascontiguousarray(f.texels, dtype=np.float32),
        "residuals": np.ascontiguousarray(f.residuals, dtype=np.float32),
        "centre": np.asarray(f.centre, dtype=np.float64),
        **{k: np.array(getattr(f, k), dtype=np.float64) for k in _SCALARS},
        "model": np.array(f.model),
        "params": np.array(json.dumps(f.params, sort_keys=True)),
        "occluder_name": np.array(f.occluder_name),
        "occluder_hash": np.array(f.occluder_hash),
        "aobake_version": np.array(__version__),
    }
    if f.table is not None:
        arrays["table"] = np.ascontiguousarray(f.table, dtype=np.float32)
    with atomic_write(path) as tmp, zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_STORED) as zf:
        for name, arr in arrays.items():
            info = zipfile.ZipInfo(name + ".npy", date_time=(1980, 1, 1, 0, 0, 0))
            with zf.open(info, "w") as fh:
                np.lib.format.write_array(fh, arr, allow_pickle=False)


def validate_field(f: AOField, where) -> None:
    """Raise :class:`InputError` (naming ``where``) unless ``f`` is internally consistent."""
    res = f.resolution
    n = res + 2
    if f.texels.shape != (6, n, n, _model.N_PARAMS):
        raise InputError(where, f"texels have shape {f.texels.shape}, expected (6, {n}, {n}, 7) for resolution {res}")
    if f.residuals.shape != (6, n, n, 2):
        raise InputError(where, f"residuals have shape {f.residuals.shape}, expected (6, {n}, {n}, 2)")
    if f.centre.shape != (3,):
        raise InputError(where, f"centre has shape {f.centre.shape}, expected (3,)")
    for name, arr in (("texels", f.texels), ("residuals", f.residuals), ("centre", f.centre)):
        if not np.isfinite(arr).all():
            raise InputError(where, f"{name} contain NaN or inf")
    if not (f.radius > 0 and math.isfinite(f.r_far) and f.r_far > f.radius and 0 <= f.r_near < f.r_far):
        raise InputError(
            where, f"inconsistent radii: radius {f.radius:.6g}, r_near {f.r_near:.6g}, r_far {f.r_far:.6g}"
        )
    if not (0.0 <= f.a0 <= 1.0 and 0.0 <= f.power < math.inf):
        raise InputError(where, f"a0 must be in [0, 1] and power >= 0, got {f.a0:.6g}, {f.power:.6g}")
    if (f.texels[..., _model.P_R0] < 0).any():
        raise InputError(where, "negative hull distances r0")
    if f.model not in MODEL_CODES:
        raise InputError(where, f"unknown model {f.model!r} (expected one of {', '.join(MODEL_CODES)})")
    if not (0.0 < f.d_min < f.d_max < math.inf):
        raise InputError(where, f"inconsistent radial layout: d_min {f.d_min:.6g}, d_max {f.d_max:.6g}")
    if f.model == "table":
        shape = None if f.table is None else f.table.shape
        if shape is None or len(shape) != 5 or shape[:3] != (6, n, n) or shape[3] < 2 or shape[4] != 4:
            raise InputError(where, f"table has shape {shape}, expected (6, {n}, {n}, M >= 2, 4)")
        if not np.isfinite(f.table).all():
            raise InputError(where, "table contains NaN or inf")


def load_field(path: str | Path) -> AOField:
    """Read a field written by :func:`save_field`; validate everything.

    Raises
    ------
    InputError
        One line naming the file: unreadable or not an npz, truncated, a missing key,
        a wrong dtype or shape, another format version, or inconsistent values.
    """
    path = check_input_file(path, "field file")
    try:
        with np.load(path, allow_pickle=False) as z:
            names = set(z.files)
            missing = [k for k in _KEYS if k not in names]
            if missing:
                raise InputError(path, f"not an aobake field file: missing {', '.join(missing)}")
            data = {k: z[k] for k in _KEYS}
            table = z["table"] if "table" in names else None
    except InputError:
        raise
    except FileNotFoundError:
        raise InputError(path, "no such file") from None
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError) as exc:
        reason = str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__
        raise InputError(path, f"not a readable field file ({reason})") from None
    version = data["format_version"]
    if version.shape != () or version.dtype.kind not in "iu":
        raise InputError(path, "format_version must be an integer scalar")
    if int(version) != FORMAT_VERSION:
        raise InputError(path, f"field format version {int(version)} is not supported (expected {FORMAT_VERSION})")
    res = data["resolution"]
    if res.shape != () or res.dtype.kind not in "iu" or int(res) < 1:
        raise InputError(path, "resolution must be a positive integer scalar")
    for k in ("texels", "residuals", "centre"):
        if data[k].dtype.kind != "f":
            raise InputError(path, f"{k} must be floating point, got {data[k].dtype}")
    if table is not None and table.dtype.kind != "f":
        raise InputError(path, f"table must be floating point, got {table.dtype}")
    for k in _SCALARS:
        if data[k].shape != () or data[k].dtype.kind not in "fiu":
            raise InputError(path, f"{k} must be a number")
    for k in _STRINGS:
        if data[k].shape != () or data[k].dtype.kind != "U":
            raise InputError(path, f"{k} must be a string")
    try:
        params = json.loads(str(data["params"]))
        if not isinstance(params, dict):
            raise ValueError
    except ValueError:
        raise InputError(path, "params is not a JSON object") from None
    f = AOField(
        texels=data["texels"].astype(np.float32),
        residuals=data["residuals"].astype(np.float32),
        centre=data["centre"].astype(np.float64),
        radius=float(data["radius"]),
        r_far=float(data["r_far"]),
        r_near=float(data["r_near"]),
        a0=float(data["a0"]),
        power=float(data["power"]),
        resolution=int(res),
        model=str(data["model"]),
        table=None if table is None or str(data["model"]) != "table" else table.astype(np.float32),
        d_min=float(data["d_min"]),
        d_max=float(data["d_max"]),
        params=params,
        occluder_name=str(data["occluder_name"]),
        occluder_hash=str(data["occluder_hash"]),
    )
    validate_field(f, path)
    return f
