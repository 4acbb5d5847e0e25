"""Exact occlusion of simple occluders: a coaxial disk, and any planar polygon (Lambert's
form factor, the solid angle) clipped to a receiver's tangent plane."""

from __future__ import annotations

import numpy as np


def disk_on_axis_cosine(radius: float, height: float) -> float:
    """Cosine-weighted occlusion of a point facing a coaxial disk: R^2 / (R^2 + h^2)."""
    return radius**2 / (radius**2 + height**2)


def disk_on_axis_solid_angle(radius: float, height: float) -> float:
    """Uniform (solid-angle) occlusion of the same: Omega / 2 pi = 1 - h / sqrt(R^2 + h^2)."""
    return 1.0 - height / np.sqrt(radius**2 + height**2)


def clip_polygon(corners, point, normal):
    """Sutherland-Hodgman: the part of a planar polygon with ``normal.(x - point) >= 0``."""
    out = []
    k = len(corners)
    for a in range(k):
        x0, x1 = corners[a], corners[(a + 1) % k]
        h0, h1 = np.dot(normal, x0 - point), np.dot(normal, x1 - point)
        if h0 >= 0:
            out.append(x0)
        if (h0 >= 0) != (h1 >= 0):
            out.append(x0 + h0 / (h0 - h1) * (x1 - x0))
    return out


def polygon_form_factor(corners, point, normal):
    """Lambert: cosine-weighted occlusion of ``point`` by a planar polygon (either winding),
    after clipping it to the tangent plane; arccos form of the contour sum
    F = 1/(2 pi) |sum_i angle_i (n . unit(v_i x v_{i+1}))|."""
    point = np.asarray(point, dtype=float)
    normal = np.asarray(normal, dtype=float)
    poly = clip_polygon([np.asarray(c, dtype=float) for c in corners], point, normal)
    if len(poly) < 3:
        return 0.0
    u = [(c - point) / np.linalg.norm(c - point) for c in poly]
    total = 0.0
    for a in range(len(u)):
        v0, v1 = u[a], u[(a + 1) % len(u)]
        cross = np.cross(v0, v1)
        s = np.linalg.norm(cross)
        if s == 0:
            continue
        total += np.arccos(np.clip(np.dot(v0, v1), -1, 1)) * np.dot(normal, cross) / s
    return abs(total) / (2 * np.pi)


def polygon_solid_angle(corners, point, normal):
    """Solid angle / 2 pi of the clipped polygon: a fan of van Oosterom-Strackee triangles."""
    point = np.asarray(point, dtype=float)
    normal = np.asarray(normal, dtype=float)
    poly = clip_polygon([np.asarray(c, dtype=float) for c in corners], point, normal)
    total = 0.0
    for a in range(1, len(poly) - 1):
        r1, r2, r3 = poly[0] - point, poly[a] - point, poly[a + 1] - point
        l1, l2, l3 = np.linalg.norm(r1), np.linalg.norm(r2), np.linalg.norm(r3)
        num = np.dot(r1, np.cross(r2, r3))
        den = l1 * l2 * l3 + np.dot(r1, r2) * l3 + np.dot(r1, r3) * l2 + np.dot(r2, r3) * l1
        total += 2 * np.arctan2(num, den)
    return abs(total) / (2 * np.pi)
