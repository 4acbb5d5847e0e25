"""Defaults, dtypes and relative tolerances, each with the reason for its value.

Imports only numpy.
"""

from __future__ import annotations

import numpy as np

# numba fastmath flags, for the disk method's tree pass only (kernels/treepass.py and its
# list sums: their loops vectorise only if LLVM may reassociate the sums). Every other kernel rounds as
# written: numba links a copy of each callee (and of a parallel kernel's body) into its
# caller and optimises it again there, fastmath lets LLVM round that copy differently,
# and which copy runs depends on what was compiled or loaded from the cache first
# (docs/first-run.md, issue 19). "nnan" and "ninf" are left out: NaN/inf tests must hold.
FASTMATH = {"nsz", "arcp", "contract", "afn", "reassoc"}

FLOAT = np.float64
INDEX = np.int64

# The two measures of occlusion and the codes the kernels take for them.
MEASURE_COSINE = 0
MEASURE_UNIFORM = 1
MEASURE_CODES = {"cosine": MEASURE_COSINE, "uniform": MEASURE_UNIFORM}

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

# Mesh extent (largest bounding-box side) aobake accepts. AO does not depend on scale:
# the ray tracer divides coordinates by a power of two (exact) before Embree's float32,
# the disk method by the extent. Areas, cross products and squared distances are formed
# in float64 in mesh units, and a norm of a cross product squares it again: fourth
# powers of 1e+-60 stay well inside float64's 1e+-308.
MIN_EXTENT = 1e-60
MAX_EXTENT = 1e60

# Unbounded rays: Embree's tfar for "no max distance" (float32-safe, beyond any scene).
INFINITE_DISTANCE = 1e30

# Adaptive sampling: rays are cast in rounds; every round ends on a power of two so the
# (0,2)-sequence prefix stays fully stratified. ADAPTIVE_FIRST_ROUND rays before any test.
ADAPTIVE_FIRST_ROUND = 16
# Two-sided 95% normal quantile for the confidence-interval half-width.
Z95 = 1.959963984540054

# Rays per Embree call: ~1M rays is 28 MB of float32 origins+directions, large enough
# to amortise the call and small enough to keep per-chunk memory flat on big meshes.
CHUNK_RAYS = 1 << 20

# A bake's Embree scene is built on a thread of its own while the mesh's normals and
# contact points are computed, up to this many vertices: on two cores that hides most of
# the build (~0.4 s of a 721k-vertex bake), but the BVH's memory (~230 bytes per vertex
# at its peak) then adds to theirs (~150) instead of following them, so larger meshes,
# where memory is what limits, build it after them (docs/process.md).
EARLY_SCENE_MAX_VERTICES = 2_000_000

# Rays (or paths) the light transport makes and traces together through buffers made
# once per chunk: their records (~0.1 kB a ray, ~0.3 kB a path) stay near a core's
# cache instead of being faulted in anew (2048-16384 measured alike on the box).
BLOCK_RAYS = 8192

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

# Disk method (aobake.methods.bunnell, aobake.kernels.bunnell / hierarchy / polygon) ------------

# Near field: a receiver closer to a triangle's plane than this many edge lengths
# (sqrt(2 area)) sees the triangle edge-on and gets nothing from it. Relative, so scale
# invariant; 1e-6 is far below any real gap between surfaces but above the rounding of
# recentred float64 coordinates (a receiver on the triangle's own plane, e.g. its own
# corner, computes h ~ 1e-16 of the edge length).
NEAR_PLANE_REL = 1e-6

# Receivers are evaluated at p + NEAR_OFFSET_REL * sqrt(A_p) * n (A_p: the vertex's disk
# area, ~ an edge length squared), the disk method's analogue of a ray origin offset: a
# face lying on the receiver's own plane (a box resting on another, the far side of a
# solid whose face meets the receiver's face at a crease) is then seen from the side the
# normal points to, as a ray from the surface would see it. 100x NEAR_PLANE_REL, so such
# faces are never taken as edge-on; 1e-4 edge lengths changes no other term measurably.
NEAR_OFFSET_REL = 1e-4

# The disk method's light: each area light (and a scene's emitting triangles together) is
# Meshes of at most this many vertices are baked by the disk method (AO and light) on one
# thread unless the options name a count: each kernel call is then a few milliseconds of
# work, and waking the pool's threads costs more than they save (the bundled box, 1,037
# vertices, at load 10 on 2 cores: its light 0.033 s of CPU on one thread against 0.158 s
# on two, its AO 0.023 against 0.043). Results do not depend on the count.
SERIAL_VERTICES = 2048

# cut into about this many emitting disks of equal area. The transfer's error falls about
# 4x per halving of a disk's size (docs/bunnell-light.md): 256 cells keep a light's own
# error below 1% at distances above ~1/10 of its size, at a cost the vertex disks dwarf.
LIGHT_DISKS = 256

# An emitter closer to the receiver than sqrt(COINCIDENT_REL * A) is treated as the same
# point (split vertices share a position) and skipped when its disk is used: relative to
# the emitter's own size, so the test is scale invariant; 1e-12 means r < 1e-6 disk radii.
COINCIDENT_REL = 1e-12

# Tree keys: positions quantised to this many steps of the scene's largest extent. Integer
# keys make the tree topology (and so the result) exactly invariant under scaling and
# translation unless a coordinate falls within rounding of a step boundary; 2**20 steps
# keep ~1e-6 of the extent as resolution, far finer than any useful split.
TREE_KEY_STEPS = 1 << 20

# Pending-range stack of the iterative tree build. Median splits halve the range, so the
# stack never holds more than ~log2(k) + 2 entries; 128 covers any k < 2**120.
TREE_BUILD_STACK = 128

# Opening the disk method's cluster tree (aobake.methods.bunnell.tree.pack_nodes): a node
# whose disks' normals disagree is a poor point emitter (one whose disks lie on two facing plates, or on
# both sides of a ball, has its centre in the empty space between them), so its opening
# distance grows with the disagreement: open_d2 = theta max(A, pi b^2) (1 + OPEN_COHERENCE
# (1 - |sum A m| / sum A)). 0 is the published criterion; 3 is more accurate on every
# bench scene for a little more time per pass (docs/bunnell.md).
OPEN_COHERENCE = 3.0

# Passes >= 2 (aobake.methods.bunnell.passes): an emitter at distance r from a receiver is weighted by its
# own accessibility from the geometry within PASS_REACH * r of it, read off distance bins
# with these outer radii (normalised units: the scene's largest extent is 1). A factor of
# 4 between bins was as accurate as 2 on the bench scenes at half the bins; the last
# radius exceeds the normalised diagonal sqrt(3), so the last bin is "everything".
PASS_RADII = (0.005, 0.02, 0.08, 0.32, 1.28, 5.12)

# Passes >= 2, gated weights: an emitter's occlusion only lowers its weight for a receiver
# whose tangent plane has the emitter's occluders (their form-factor-weighted centroid)
# in front of it: by min(1, h / (PASS_GATE_WIDTH r)), h = that centroid's height above
# the plane, r = the receiver-emitter distance. Occluders behind the receiver's plane (the
# receiver's own surface: the facing plate, the ball above its shadow) hide nothing from
# it. Widths 0.02 to 0.1 give the same accuracy (docs/bunnell.md).
PASS_GATE_WIDTH = 0.1

# Per-direction saturation (aobake.methods.bunnell, cosine measure): each receiver's disk and
# cluster terms are spread over DIRECTION_SECTORS azimuth sectors x 2 elevation bands of
# equal cosine-weighted measure (1 / (2 S) each) and no band holds more than it can: where
# stacked layers (a ball behind a ball, the floor seen through a body) overfill a bin the
# excess is dropped. The near-field cells are added unbinned, and so is every disk or
# cluster with area A >= DIRECTION_WIDE r^2, whose term A cos cos / (pi r^2 + A) may not
# fit the (at most 4) bins it is spread over: below DIRECTION_WIDE = 1 a term is at most
# 1 / (pi + 1) = 0.24 < 4 / 16 (without this, the contact vertex of two touching balls
# read ao 0.875 with disks only, where the truth is 0). Smaller DIRECTION_WIDE undoes the
# gain; 8 sectors beat 4 (docs/bunnell.md).
DIRECTION_SECTORS = 8
DIRECTION_WIDE = 1.0

#: What a bake can compute, in order (``--effects``): the AO, the lights' direct light,
#: and the light bounced between surfaces. ``auto`` computes what the scene calls for.
EFFECTS = ("ao", "direct", "indirect")
