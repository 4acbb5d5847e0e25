"""Compiled aimed shadow pass through the occluders' cluster tree: ``lightshadow.aimed_shadow``
with the occluders in a tree that each receiver walks, skipping whole clusters outside
the cone of the light patches it sees, beyond the farthest patch or behind its tangent
plane (all exact: their occluders add nothing), and taking a cluster far for its size
as one occluder (its projected area and its light-weighted visibility from its sums).

Imports numpy, numba, ``aobake.constants`` and other kernels only. numba caches each
kernel by its own file's time stamp: after changing the inlined ``lightshadow._cap`` or
``_overlap``, touch this file. The helpers are not inlined: the same speed, and the cold
compile 5 s of CPU instead of 8. Symbols as in ``aobake.kernels.lightshadow``; the tree is
``aobake.kernels.hierarchy``'s (preorder, skip pointers), the occluders in tree order.

Node rows (float64): centre, bounding radius (disks included), summed area A, squared
distance beyond which the node is used whole, ``kappa^2 T / A`` (T = sum A m m^T: so
``sqrt(u^T (kappa^2 T / A) u)`` estimates the mean ``|m.u|``, ``hierarchy.spread_factor``),
the number of occluders with light on a side (N_LIT: 0 = the node adds nothing), then per
light group g: ``S_g = sum A (v_0 + v_1) / 2`` and ``D_g = sum A (v_0 - v_1) m / 2``
(v_s: the fraction of g's light reaching side s), so that ``a S_g + D_g.u`` is the
visibility-weighted projected area ``sum A |m.u| v_side``, exact for one disk.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from aobake.constants import COINCIDENT_REL

from .lightshadow import O_A, O_C, O_M, Q_A, Q_C, Q_GROUP, Q_L, Q_M, _cap, _overlap

N_C, N_B, N_A, N_OPEN_D2, N_T, N_LIT, N_G = 0, 3, 4, 5, 6, 12, 13
N_GROUP_COLS = 4  # S_g, D_g (3)
# Depth of the walk's stack: one pending sibling per level of the tree (a median-split
# tree over k disks is about log2(k / leaf) deep).
STACK_DEPTH = 128
# Slack of the cosine test that an occluder's cap is apart from a patch's (far above the
# rounding of the cosines): within it the overlap is computed (0 or not).
REJECT_SLACK = 1e-9


@njit(cache=True, error_model="numpy")
def _covered(cover, w_q):
    """Every patch seen is covered (its share saturated at 1)."""
    for q in range(w_q.shape[0]):
        if w_q[q] > 0.0 and cover[q] < 1.0:
            return False
    return True


@njit(cache=True, error_model="numpy")
def _straddles(cover, w_q, cos_q, sin_q, ux_q, uy_q, uz_q, ux, uy, uz, sin_a, edge):
    """Some patch's cap (not yet covered, of angular radius above ``asin(sin_a) / edge``
    in sines) has its edge within angle ``asin(sin_a)`` of direction u: a node of that
    angular radius there may cover part of it, which one cap at its centre does not tell
    (it is opened instead). Nodes small against the cap (``edge`` of it) are not opened:
    their misplaced share is small."""
    cos_a = math.sqrt(max(0.0, 1.0 - sin_a * sin_a))
    for q in range(w_q.shape[0]):
        if w_q[q] <= 0.0 or cover[q] >= 1.0 or sin_a <= edge * sin_q[q]:
            continue
        cos_b = ux * ux_q[q] + uy * uy_q[q] + uz * uz_q[q]
        # beta in (a_q - alpha, a_q + alpha), alpha = asin(sin_a), padded by the slack
        outer = cos_q[q] * cos_a - sin_q[q] * sin_a  # cos(a_q + alpha)
        inner = cos_q[q] * cos_a + sin_q[q] * sin_a if sin_q[q] > sin_a else 1.0  # cos(a_q - alpha)
        if outer - REJECT_SLACK < cos_b < inner + REJECT_SLACK:
            return True
    return False


@njit(cache=True, error_model="numpy")
def _cover(cover, w_q, a_q, cos_q, sin_q, d2_q, ux_q, uy_q, uz_q, patches, r2, ux, uy, uz, projected, vis_g):
    """Add one occluder (``projected`` area at unit direction u and squared distance
    ``r2``, visibility ``vis_g[g]`` per group) to every patch it is nearer than, as
    ``lightshadow.aimed_shadow`` does; a patch whose cap is clearly apart from the
    occluder's (``cos_b`` below ``cos(a_j + a_q)`` by REJECT_SLACK) is passed over without
    the overlap (it is 0)."""
    w_j, a_j = _cap(r2, projected)
    cos_j = math.sqrt(r2 / (r2 + projected / math.pi))
    sin_j = math.sqrt((projected / math.pi) / (r2 + projected / math.pi))
    for q in range(patches.shape[0]):
        if w_q[q] <= 0.0 or d2_q[q] <= r2 or cover[q] >= 1.0:  # a covered patch stays covered
            continue
        cos_b = ux * ux_q[q] + uy * uy_q[q] + uz * uz_q[q]
        if cos_b <= 0.0 or cos_b < cos_j * cos_q[q] - sin_j * sin_q[q] - REJECT_SLACK:
            continue
        f = _overlap(a_j, a_q[q], math.acos(min(1.0, cos_b)))
        if f > 0.0:
            cover[q] += min(w_j, w_q[q]) * f * vis_g[int(patches[q, Q_GROUP])] / w_q[q]


@njit(cache=True, error_model="numpy", parallel=True)
def aimed_shadow_tree(points, normals, skip, start, stop, nodes, occ, own, vis, patches, edge, reach2, out):
    """``out[i, g]``: ``lightshadow.aimed_shadow``'s blocked fraction with the occluders
    in a tree (``occ``, ``own``, ``vis`` in tree order). Each receiver walks the tree: a
    node is skipped when every occluder in it would be (farther than every patch seen,
    behind the tangent plane, or outside the cone of the patches by more than its own
    cap); used whole when the receiver is beyond ``sqrt(nodes[q, N_OPEN_D2])`` from its
    centre, in front of its plane and nearer than every patch, as one occluder at its
    centre of projected area ``P = min(a A, pi b^2)`` (``a`` the estimated mean ``|m.u|``) and
    visibility ``(a S_g + D_g.u) / P`` clipped to [0, 1]; else opened (a leaf's
    occluders exactly as the brute-force kernel). With every node opened the result is the
    brute-force kernel's (the same terms, summed in tree order).

    Parameters
    ----------
    points, normals : (n, 3) float64
    skip, start, stop : (m,) int64
    nodes : (m, N_G + N_GROUP_COLS G) float64
    occ : (k, O_SIZE) float64
    own : (k,) int64
    vis : (k, 2, G) float64
    patches : (P, Q_SIZE) float64
    edge : float >= 0
        Nodes across a patch cap's edge are used whole when their angular radius is at
        most ``edge`` times the cap's (sines); 0: always opened.
    reach2 : float
        Occluders farther than ``sqrt(reach2)`` block nothing (as the brute-force kernel);
        a node is skipped when all of it is beyond, used whole only when all of it is within.
    out : (n, G) float64
        Overwritten.
    """
    n = points.shape[0]
    n_patches = patches.shape[0]
    n_groups = out.shape[1]
    for i in prange(n):
        for g in range(n_groups):
            out[i, g] = 0.0
        nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
        if nx == 0.0 and ny == 0.0 and nz == 0.0:
            continue
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        ux_q = np.empty(n_patches)
        uy_q = np.empty(n_patches)
        uz_q = np.empty(n_patches)
        d2_q = np.empty(n_patches)
        w_q = np.zeros(n_patches)
        a_q = np.zeros(n_patches)
        c_q = np.zeros(n_patches)
        cover = np.zeros(n_patches)
        cos_q = np.zeros(n_patches)
        sin_q = np.zeros(n_patches)
        vis_g = np.empty(n_groups)
        for q in range(n_patches):
            tx, ty, tz = patches[q, Q_C] - px, patches[q, Q_C + 1] - py, patches[q, Q_C + 2] - pz
            d2 = tx * tx + ty * ty + tz * tz
            d = math.sqrt(d2)
            d2_q[q] = d2
            if not d > 0.0:
                continue
            tx, ty, tz = tx / d, ty / d, tz / d
            ux_q[q], uy_q[q], uz_q[q] = tx, ty, tz
            cq = -(patches[q, Q_M] * tx + patches[q, Q_M + 1] * ty + patches[q, Q_M + 2] * tz)
            cos_r = nx * tx + ny * ty + nz * tz
            if cq <= 0.0 or cos_r <= 0.0:
                continue
            w_q[q], a_q[q] = _cap(d2, patches[q, Q_A] * cq)
            cos_q[q], sin_q[q] = math.cos(a_q[q]), math.sin(a_q[q])
            c_q[q] = cos_r * (patches[q, Q_L] + patches[q, Q_L + 1] + patches[q, Q_L + 2])
        ax, ay, az, far2, near2 = 0.0, 0.0, 0.0, 0.0, np.inf
        for q in range(n_patches):
            if w_q[q] > 0.0:
                ax += ux_q[q]
                ay += uy_q[q]
                az += uz_q[q]
                far2 = max(far2, d2_q[q])
                near2 = min(near2, d2_q[q])
        norm = math.sqrt(ax * ax + ay * ay + az * az)
        if not norm > 0.0:
            continue
        ax, ay, az = ax / norm, ay / norm, az / norm
        spread = 0.0
        for q in range(n_patches):
            if w_q[q] > 0.0:
                cos_axis = min(1.0, max(-1.0, ax * ux_q[q] + ay * uy_q[q] + az * uz_q[q]))
                spread = max(spread, math.acos(cos_axis) + a_q[q])
        far = math.sqrt(far2)
        # nearer child first, and stop once every patch seen is covered (min(1, C) cannot change)
        stack = np.empty(STACK_DEPTH, dtype=np.int64)
        stack[0] = 0
        sp = 1
        while sp > 0:
            sp -= 1
            node = stack[sp]
            dx, dy, dz = nodes[node, N_C] - px, nodes[node, N_C + 1] - py, nodes[node, N_C + 2] - pz
            b = nodes[node, N_B]
            d2 = dx * dx + dy * dy + dz * dz
            d = math.sqrt(d2)
            height = nx * dx + ny * dy + nz * dz
            if height <= -b or d - b >= far or nodes[node, N_LIT] <= 0.0 or (d - b) * (d - b) > reach2 and d > b:
                continue  # every centre behind the plane, beyond every patch or reach, or no light on any side
            if d > b:
                # outside the cone by more than any of its occluders' caps: the angle to
                # the axis >= spread + asin(b / d) + atan(b / (d - b)) (bounded above)
                lim = spread + 0.5 * math.pi * b / d + b / (d - b)
                if lim < math.pi and ax * dx + ay * dy + az * dz <= d * math.cos(lim) - REJECT_SLACK * d:
                    continue
                if d2 >= nodes[node, N_OPEN_D2] and height >= b and (d + b) * (d + b) < near2 and (d + b) * (d + b) <= reach2 and not _straddles(
                        cover, w_q, cos_q, sin_q, ux_q, uy_q, uz_q, dx / d, dy / d, dz / d, b / d, edge):
                    ux, uy, uz = dx / d, dy / d, dz / d
                    t = N_T
                    quad = (nodes[node, t] * ux * ux + nodes[node, t + 1] * uy * uy + nodes[node, t + 2] * uz * uz
                            + 2.0 * (nodes[node, t + 3] * ux * uy + nodes[node, t + 4] * ux * uz
                                     + nodes[node, t + 5] * uy * uz))  # fmt: skip
                    a = math.sqrt(max(quad, 0.0))
                    # its projected area, at most its bounding sphere's (layers stacked along u
                    # cover it once); the light-weighted projected area per group over that
                    proj = min(a * nodes[node, N_A], math.pi * b * b)
                    if proj > 0.0:
                        for g in range(n_groups):
                            c = N_G + N_GROUP_COLS * g
                            x = a * nodes[node, c] + nodes[node, c + 1] * ux + nodes[node, c + 2] * uy + nodes[node, c + 3] * uz
                            vis_g[g] = min(1.0, max(0.0, x / proj))
                        _cover(cover, w_q, a_q, cos_q, sin_q, d2_q, ux_q, uy_q, uz_q, patches, d2, ux, uy, uz, proj, vis_g)
                        if _covered(cover, w_q):
                            break
                    continue
            if skip[node] != node + 1:
                left = node + 1
                right = skip[left]
                lx, ly, lz = nodes[left, N_C] - px, nodes[left, N_C + 1] - py, nodes[left, N_C + 2] - pz
                rx, ry, rz = nodes[right, N_C] - px, nodes[right, N_C + 1] - py, nodes[right, N_C + 2] - pz
                if lx * lx + ly * ly + lz * lz <= rx * rx + ry * ry + rz * rz:
                    stack[sp] = right
                    stack[sp + 1] = left
                else:
                    stack[sp] = left
                    stack[sp + 1] = right
                sp += 2
                continue
            for j in range(start[node], stop[node]):
                if own[j] == i:
                    continue
                dx, dy, dz = occ[j, O_C] - px, occ[j, O_C + 1] - py, occ[j, O_C + 2] - pz
                r2 = dx * dx + dy * dy + dz * dz
                area = occ[j, O_A]
                if r2 <= COINCIDENT_REL * area or nx * dx + ny * dy + nz * dz <= 0.0 or r2 >= far2 or r2 > reach2:
                    continue
                r = math.sqrt(r2)
                ux, uy, uz = dx / r, dy / r, dz / r
                md = occ[j, O_M] * ux + occ[j, O_M + 1] * uy + occ[j, O_M + 2] * uz
                side = 0 if md > 0.0 else 1
                lit = 0.0
                for g in range(n_groups):
                    vis_g[g] = vis[j, side, g]
                    lit += vis_g[g]
                if lit <= 0.0:
                    continue  # no light on the side it blocks: it adds nothing
                w_j, a_j = _cap(r2, area * abs(md))
                if math.acos(min(1.0, max(-1.0, ax * ux + ay * uy + az * uz))) >= spread + a_j:
                    continue
                _cover(cover, w_q, a_q, cos_q, sin_q, d2_q, ux_q, uy_q, uz_q, patches, r2, ux, uy, uz, area * abs(md), vis_g)
            if _covered(cover, w_q):
                break
        for g in range(n_groups):
            total = 0.0
            blocked = 0.0
            for q in range(n_patches):
                if int(patches[q, Q_GROUP]) != g or w_q[q] <= 0.0:
                    continue
                total += w_q[q] * c_q[q]
                blocked += w_q[q] * c_q[q] * min(1.0, cover[q])
            out[i, g] = blocked / total if total > 0.0 else 0.0
