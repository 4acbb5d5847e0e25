"""Colour encodings of ``ao`` written as vertex colours, said once for every format.

USD ``displayColor`` and glTF ``COLOR_0`` hold linear values (both specifications say
so). PLY colour bytes carry no colour space, and Blender and MeshLab decode them as
sRGB, so PLY ``--color`` bytes are sRGB-encoded: every viewer then shows the same grey.
``--channel`` packing is data, not a colour: linear in every format.

Imports numpy only.
"""

from __future__ import annotations

import numpy as np

#: The vertex-colour channel names ``--channel`` takes, and their column.
CHANNELS = {"R": 0, "G": 1, "B": 2, "A": 3}


def linear_to_srgb(x) -> np.ndarray:
    """The sRGB transfer function (IEC 61966-2-1) of linear values in [0, 1], float64."""
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def srgb_to_linear(s) -> np.ndarray:
    """The inverse of :func:`linear_to_srgb`: what a viewer decoding sRGB shows, float64."""
    s = np.clip(np.asarray(s, dtype=np.float64), 0.0, 1.0)
    return np.where(s <= 0.04045, s / 12.92, np.power((s + 0.055) / 1.055, 2.4))


def srgb_bytes(ao) -> np.ndarray:
    """``ao`` as sRGB-encoded 8-bit grey (PLY ``red green blue``), uint8."""
    return np.rint(linear_to_srgb(ao) * 255.0).astype(np.uint8)


def quantize(values, dtype) -> np.ndarray:
    """Linear values in [0, 1] stored as ``dtype``: floats as they are, unsigned integers
    as normalised ``round(v * max)`` (glTF's and PLY's convention for colour integers)."""
    dtype = np.dtype(dtype)
    values = np.asarray(values, dtype=np.float64)
    if dtype.kind == "f":
        return values.astype(dtype)
    top = float(np.iinfo(dtype).max)
    return np.rint(np.clip(values, 0.0, 1.0) * top).astype(dtype)
