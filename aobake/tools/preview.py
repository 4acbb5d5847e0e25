"""Preview images of a bake: the AO as grey (or the vertex colours), rendered on the CPU, written as PNG.

Arrays in, PNG bytes out (zlib from the standard library: no imaging dependency).
Camera: perspective, looking at the bounding-box centre from an azimuth/elevation about
the up axis, framed to fit the bounding sphere.
"""

from __future__ import annotations

import math
import struct
import zlib
from pathlib import Path

import numpy as np

from ..io import atomic_write
from ..kernels import render as _k
from .views import VIEWS  # (azimuth, elevation) of each named view, degrees from +X

BACKGROUND = 0.82  # light grey, so fully open (white) surfaces stand out
FOV_DEGREES = 30.0


def camera(positions, *, up: str = "Y", azimuth: float = -55.0, elevation: float = 30.0):
    """Camera frame (eye, right, true up, forward) looking at the bounding-box centre."""
    lo, hi = positions.min(axis=0), positions.max(axis=0)
    centre = 0.5 * (lo + hi)
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-300)
    up_vec = np.array([0.0, 1.0, 0.0]) if up.upper() == "Y" else np.array([0.0, 0.0, 1.0])
    # a right-handed horizontal basis (h1, h2) with h1 x h2 = up
    h1 = np.array([1.0, 0.0, 0.0])
    h2 = np.cross(up_vec, h1)
    az, el = math.radians(azimuth), math.radians(elevation)
    direction = math.cos(el) * (math.cos(az) * h1 + math.sin(az) * h2) + math.sin(el) * up_vec
    distance = radius / math.sin(math.radians(FOV_DEGREES) / 2) * 1.05
    eye = centre + distance * direction
    forward = -direction
    right = np.cross(forward, up_vec)
    if np.linalg.norm(right) < 1e-9:  # looking straight along the up axis
        right = h1.copy()
    right /= np.linalg.norm(right)
    true_up = np.cross(right, forward)
    return eye, right, true_up, forward


#: Rows rendered at a time by :func:`preview_png`: 256 rows of an 8192-pixel image are
#: 16 MB per float64 buffer, where the whole image took 6.8 GB at its peak.
BAND_ROWS = 256


def render_values(
    positions,
    faces,
    values,
    *,
    size: int = 640,
    up: str = "Y",
    view: str = "iso",
    azimuth=None,
    elevation=None,
):
    """A (size, size) float image of per-vertex ``values`` on the visible surface; NaN
    where no surface is seen.

    Parameters
    ----------
    positions : (n, 3) float
    faces : (m, 3) int
    values : (n,) float
    size : int
    up : {"Y", "Z"}
    view : one of VIEWS, overridden by ``azimuth``/``elevation`` (degrees) when given.
    """
    draw = _band_renderer(positions, faces, values, size, up, view, azimuth, elevation)
    return draw(0, size)


def _band_renderer(positions, faces, values, size, up, view, azimuth, elevation):
    """``draw(row0, rows)``: rows ``row0 .. row0 + rows - 1`` of :func:`render_values`'s
    image, bit for bit (every pixel is computed alone)."""
    positions = np.asarray(positions, dtype=np.float64)
    az, el = VIEWS[view]
    az = az if azimuth is None else float(azimuth)
    el = el if elevation is None else float(elevation)
    eye, right, true_up, forward = camera(positions, up=up, azimuth=az, elevation=el)
    rel = positions - eye
    z = rel @ forward
    f = 0.5 * size / math.tan(math.radians(FOV_DEGREES) / 2)
    safe = np.where(z > 0, z, 1.0)
    screen = np.empty((positions.shape[0], 3))
    screen[:, 0] = 0.5 * size + f * (rel @ right) / safe
    screen[:, 1] = 0.5 * size - f * (rel @ true_up) / safe
    screen[:, 2] = np.where(z > 0, z, -1.0)
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    values = np.ascontiguousarray(values, dtype=np.float64)

    def draw(row0: int, rows: int) -> np.ndarray:
        depth = np.full((rows, size), np.inf)
        image = np.full((rows, size), np.nan)
        _k.rasterize(screen, faces, values, depth, image, row0)
        return image

    return draw


def preview_png(positions, faces, values, *, size: int = 640, band_rows: int = BAND_ROWS, **view) -> bytes:
    """PNG bytes of :func:`grey` (:func:`render_values`) rendered ``band_rows`` rows at a
    time: the same file as ``png_bytes(grey(render_values(...)))``, in bounded memory.
    ``values``: (n,) AO, or (n, 3) linear RGB drawn by :func:`colour` (sRGB-encoded).
    ``view``: ``up``, ``view``, ``azimuth``, ``elevation`` as for :func:`render_values`."""
    values = np.asarray(values, dtype=np.float64)
    channels = [values] if values.ndim == 1 else [values[:, c] for c in range(3)]
    draws = [
        _band_renderer(
            positions,
            faces,
            v,
            size,
            view.get("up", "Y"),
            view.get("view", "iso"),
            view.get("azimuth"),
            view.get("elevation"),
        )
        for v in channels
    ]
    deflate = zlib.compressobj(6)
    parts = []
    for row0 in range(0, size, band_rows):
        rows = min(band_rows, size - row0)
        if values.ndim == 1:
            pixels = _pixels(grey(draws[0](row0, rows)))
        else:
            pixels = _pixels(colour(np.stack([d(row0, rows) for d in draws], axis=-1)))
        filtered = np.concatenate([np.zeros((rows, 1), dtype=np.uint8), pixels.reshape(rows, -1)], axis=1)
        parts.append(deflate.compress(filtered.tobytes()))
    parts.append(deflate.flush())
    return _png(size, size, 2, b"".join(parts))


def grey(image) -> np.ndarray:
    """(h, w, 3) RGB of an AO image (NaN background drawn light grey)."""
    g = np.where(np.isnan(image), BACKGROUND, np.clip(image, 0.0, 1.0))
    return np.repeat(g[..., None], 3, axis=2)


def colour(image) -> np.ndarray:
    """(h, w, 3) sRGB-encoded pixels of a linear RGB image (NaN background light grey),
    so the PNG shows the colours a viewer shows on the mesh."""
    from ..io.color import linear_to_srgb

    image = np.asarray(image, dtype=np.float64)
    background = np.isnan(image).any(axis=-1)
    out = linear_to_srgb(np.nan_to_num(image))
    out[background] = BACKGROUND
    return out


def png_bytes(image) -> bytes:
    """8-bit greyscale (h, w) or RGB (h, w, 3) PNG of a float image in [0, 1]."""
    pixels = _pixels(image)
    h, w = pixels.shape[:2]
    colour = 2 if pixels.ndim == 3 else 0
    rows = np.concatenate([np.zeros((h, 1), dtype=np.uint8), pixels.reshape(h, -1)], axis=1)
    return _png(w, h, colour, zlib.compress(rows.tobytes(), 6))


def _pixels(image) -> np.ndarray:
    """uint8 pixels of a float image in [0, 1]."""
    img = np.clip(np.asarray(image, dtype=np.float64), 0.0, 1.0)
    return np.round(img * 255.0).astype(np.uint8)


def _png(w: int, h: int, colour: int, idat: bytes) -> bytes:
    """A PNG file around compressed, filtered rows (``colour`` 0 grey, 2 RGB)."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return (
            struct.pack(">I", len(data))
            + kind
            + data
            + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)
        )

    header = struct.pack(">IIBBBBB", w, h, 8, colour, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


def error_colours(err, limit: float) -> np.ndarray:
    """(h, w, 3) diverging colours for a signed error image: blue < 0 < red, white at 0,
    NaN background light grey."""
    err = np.asarray(err)
    t = np.clip(np.nan_to_num(err) / max(limit, 1e-12), -1.0, 1.0)
    rgb = np.ones(t.shape + (3,))
    rgb[..., 0] -= np.clip(-t, 0, 1)
    rgb[..., 1] -= np.abs(t)
    rgb[..., 2] -= np.clip(t, 0, 1)
    rgb[np.isnan(err)] = BACKGROUND
    return rgb


def write_png(path: str | Path, image) -> None:
    """Write an image (a float array, or PNG bytes already made) atomically as PNG."""
    data = image if isinstance(image, bytes) else png_bytes(image)
    with atomic_write(path) as tmp:
        tmp.write_bytes(data)
