"""The edge projection's iterations as compiled passes (numba), on the CPU.

Between two of ``EdgeProjection``'s sparse solves, numpy spent ~0.45 ms on a 5k garment in
five calls (the edge vectors, their lengths, the clamp to the band, the sum back onto the
vertices, the column-major copy SuperLU wants), about as long as the solve itself; here they
are one pass over the edges (``right_hand_side``). The solve itself runs over SuperLU's
factor, all three columns in one pass and, the matrix being symmetric, over L alone (``ldl_solve``:
U = D Lᵀ, so half the factor's memory; 0.57-0.59 ms with L and U, SuperLU's own 0.66-0.68 on the 5k
dress), and the contact planes in place (``onto_planes``). Sums reach a vertex in another
order than scipy's, so results agree to float32 rounding, not bit for bit. Only
``EdgeProjection`` calls these, and only where numba imports (the torch-only path runs numpy
and SuperLU's solve).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def right_hand_side(x, first, second, low, high, target, out):
    """Fill ``out`` (V,3) float32 with ``target + Dᵀ d``: d_e the edge vector x[second] −
    x[first] scaled to its length clamped into [low_e, high_e] (the local step), Dᵀ summing
    each onto its two ends (+ at ``second``, − at ``first``). x, target (the anchor term,
    α times the input positions): (V,3) float32; first, second: (E,) int64; low, high: (E,)
    float32; returns ``out``."""
    vertices, edges = x.shape[0], first.shape[0]
    for v in range(vertices):
        out[v, 0] = target[v, 0]
        out[v, 1] = target[v, 1]
        out[v, 2] = target[v, 2]
    for e in range(edges):
        a, b = first[e], second[e]
        d0, d1, d2 = x[b, 0] - x[a, 0], x[b, 1] - x[a, 1], x[b, 2] - x[a, 2]
        length = max(np.sqrt(d0 * d0 + d1 * d1 + d2 * d2), np.float32(1e-12))
        scale = min(max(length, low[e]), high[e]) / length
        d0, d1, d2 = d0 * scale, d1 * scale, d2 * scale
        out[b, 0] += d0
        out[b, 1] += d1
        out[b, 2] += d2
        out[a, 0] -= d0
        out[a, 1] -= d1
        out[a, 2] -= d2
    return out


@numba.njit(cache=True, nogil=True)
def ldl_solve(b, perm, l_start, l_row, l_value, inverse_diagonal, work, out):
    """Fill ``out`` (V,3) float32 with A⁻¹ b for a symmetric A factored as ``P A Pᵀ = L D Lᵀ``:
    L unit lower triangular with its strict lower part in CSC (l_start (V+1,), l_row, l_value),
    ``inverse_diagonal`` (V,) float32 1/D, perm (V,) int32 (row i of A is row perm[i] of P A Pᵀ),
    work (V,3) float32 scratch. The three columns are solved in one pass over L: L y = P b
    spreading each solved row down its column, then D Lᵀ z = y gathering each row's
    solved entries from the same column; returns ``out``."""
    n = b.shape[0]
    for i in range(n):
        r = perm[i]
        work[r, 0], work[r, 1], work[r, 2] = b[i, 0], b[i, 1], b[i, 2]
    for j in range(n):
        y0, y1, y2 = work[j, 0], work[j, 1], work[j, 2]
        for k in range(l_start[j], l_start[j + 1]):
            r = l_row[k]
            v = l_value[k]
            work[r, 0] -= v * y0
            work[r, 1] -= v * y1
            work[r, 2] -= v * y2
    for j in range(n - 1, -1, -1):
        d = inverse_diagonal[j]
        z0, z1, z2 = work[j, 0] * d, work[j, 1] * d, work[j, 2] * d
        for k in range(l_start[j], l_start[j + 1]):
            r = l_row[k]
            v = l_value[k]
            z0 -= v * work[r, 0]
            z1 -= v * work[r, 1]
            z2 -= v * work[r, 2]
        work[j, 0], work[j, 1], work[j, 2] = z0, z1, z2
    for i in range(n):
        c = perm[i]
        out[i, 0], out[i, 1], out[i, 2] = work[c, 0], work[c, 1], work[c, 2]
    return out


@numba.njit(cache=True, nogil=True)
def onto_planes(x, vertex, point, normal, push):
    """``edge_projection._onto_planes`` in place on ``x`` (V,3) float32: each constrained vertex
    (C,) int64 behind its plane (point, normal: (C,3) float32) moved onto it, a vertex with
    several planes by the sum of their corrections, each measured before any is applied;
    push: (C,3) float32 scratch."""
    for c in range(vertex.shape[0]):
        v = vertex[c]
        gap = ((x[v, 0] - point[c, 0]) * normal[c, 0] + (x[v, 1] - point[c, 1]) * normal[c, 1]
               + (x[v, 2] - point[c, 2]) * normal[c, 2])
        depth = max(-gap, np.float32(0.0))
        push[c, 0], push[c, 1], push[c, 2] = depth * normal[c, 0], depth * normal[c, 1], depth * normal[c, 2]
    for c in range(vertex.shape[0]):
        v = vertex[c]
        x[v, 0] += push[c, 0]
        x[v, 1] += push[c, 1]
        x[v, 2] += push[c, 2]
    return x
