"""A small z-buffer rasterizer: per-vertex scalars interpolated over screen triangles."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def rasterize(screen, faces, values, depth, image, row0):
    """Draw triangles into ``image`` with a depth test, interpolating ``values``.

    Parameters
    ----------
    screen : (n, 3) float64
        Vertex x, y in pixels (pixel centres at +0.5) and view depth (smaller = nearer;
        vertices behind the camera have depth <= 0 and their triangles are skipped).
    faces : (m, 3) int64
    values : (n,) float64
        Interpolated with perspective-incorrect (screen-linear) barycentrics, which is
        what a preview needs.
    depth, image : (h, w) float64
        Depth buffer (start at +inf) and output (start at the background); written in place.
    row0 : int
        Screen row of ``image``'s first row: a band of rows ``row0 .. row0 + h - 1`` is
        drawn, each pixel exactly as in the whole image (memory stays one band).

    Notes
    -----
    Serial on purpose: triangles write to shared pixels, and a preview is cheap.
    """
    h, w = image.shape
    for f in range(faces.shape[0]):
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        if screen[a, 2] <= 0.0 or screen[b, 2] <= 0.0 or screen[c, 2] <= 0.0:
            continue
        x0, y0, z0 = screen[a, 0], screen[a, 1], screen[a, 2]
        x1, y1, z1 = screen[b, 0], screen[b, 1], screen[b, 2]
        x2, y2, z2 = screen[c, 0], screen[c, 1], screen[c, 2]
        area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        if area == 0.0:
            continue
        xmin = max(int(np.floor(min(x0, min(x1, x2)))), 0)
        xmax = min(int(np.ceil(max(x0, max(x1, x2)))), w - 1)
        ymin = max(int(np.floor(min(y0, min(y1, y2)))), row0)
        ymax = min(int(np.ceil(max(y0, max(y1, y2)))), row0 + h - 1)
        inv = 1.0 / area
        for py in range(ymin, ymax + 1):
            sy = py + 0.5
            for px in range(xmin, xmax + 1):
                sx = px + 0.5
                w0 = ((x1 - sx) * (y2 - sy) - (x2 - sx) * (y1 - sy)) * inv
                w1 = ((x2 - sx) * (y0 - sy) - (x0 - sx) * (y2 - sy)) * inv
                w2 = 1.0 - w0 - w1
                if w0 < 0.0 or w1 < 0.0 or w2 < 0.0:
                    continue
                z = w0 * z0 + w1 * z1 + w2 * z2
                if z < depth[py - row0, px]:
                    depth[py - row0, px] = z
                    image[py - row0, px] = w0 * values[a] + w1 * values[b] + w2 * values[c]
