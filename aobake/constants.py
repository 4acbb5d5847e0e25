"""Defaults, dtypes and relative tolerances, each with the reason for its value.

Imports only numpy.
"""

from __future__ import annotations

import numpy as np

# numba fastmath flags that keep NaN/inf semantics (stumpy's set): a miss at infinite
# distance and a NaN guard must still behave, so "nnan" and "ninf" are left out.
FASTMATH = {"nsz", "arcp", "contract", "afn", "reassoc"}

FLOAT = np.float64
INDEX = np.int64

# Embree works in float32; this is its unit roundoff.
EPS32 = float(np.finfo(np.float32).eps)

# Ray-origin offset along the normal: RAY_OFFSET_ULPS * EPS32 * (M + e_i), where M is the
# largest recentred coordinate magnitude (the rounding of every float32 coordinate) and
# e_i the longest edge at vertex i (the rounding of Embree's plane-distance term grows
# with the triangle's size). 2**8 ulps keeps self-hits out of every test scene (convex
# bodies read exactly open at 1e-5 to 1e5 scale) while staying ~1e-5 of the mesh size,
# far below any real gap; a scene-diagonal bias (peers use ~1e-3 * diagonal) pushes
# vertices that touch another surface through it.
RAY_OFFSET_ULPS = 256.0

# Contact probe: a short ray from the offset origin back along -n, past the vertex by
# max((1 + CONTACT_PROBE_SLACK) * offset, CONTACT_DEPTH * longest edge), finds another
# surface that the offset crossed, that touches the vertex, or that the vertex is sunk
# into (objects placed "on" a floor in modelling tools often sink by a fraction of an
# edge).
CONTACT_PROBE_SLACK = 1.0 / 8.0
CONTACT_DEPTH = 0.25

# Unbounded rays: Embree's tfar for "no max distance" (float32-safe, beyond any scene).
INFINITE_DISTANCE = 1e30

DEFAULT_RAYS = 256
DEFAULT_SEED = 0

# Adaptive sampling: rays are cast in rounds; every round ends on a power of two so the
# (0,2)-sequence prefix stays fully stratified. ADAPTIVE_FIRST_ROUND rays before any test.
ADAPTIVE_FIRST_ROUND = 16
# Two-sided 95% normal quantile for the confidence-interval half-width.
Z95 = 1.959963984540054

# Rays per Embree call: ~1M rays is 28 MB of float32 origins+directions, large enough
# to amortise the call and small enough to keep per-chunk memory flat on big meshes.
CHUNK_RAYS = 1 << 20

# Normals: a vertex whose summed face normals are shorter than this (relative to the
# mean face area scale) has no defined normal; it gets a fallback and a warning.
NORMAL_EPS = 1e-12

# USD stage metadata defaults (an unauthored metersPerUnit means centimetres).
DEFAULT_UP_AXIS = "Y"
DEFAULT_METERS_PER_UNIT = 1.0

# Contact detection probes the other shells in at most this many groups (one Embree
# scene and one short ray per vertex each): enough for every object of a typical scene
# to be its own group, bounded for meshes made of thousands of loose pieces.
MAX_CONTACT_GROUPS = 16
