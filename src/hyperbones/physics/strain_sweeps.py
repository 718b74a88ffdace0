"""The strain limiter's Jacobi sweeps as one compiled loop (numba), for positions on the CPU.

``StrainLimiter.project`` in torch spends most of a sweep dispatching a dozen small tensor
ops (two sparse products, the lengths, the clamp, the contact planes): ~0.2 ms a sweep on a
2.5k-vertex garment, 40 sweeps a call, 8 calls a teacher step (a fifth of a bank rollout).
Here every sweep is two passes over plain arrays with the same arithmetic, 3-4x faster
(docs/experiments/2026-11-29-strain-sweeps.md). The sums a vertex receives are added in
another order than torch's sparse product, so results agree to float32 rounding, not bit
for bit. Only ``StrainLimiter`` calls this, and only without gradients and with numba
importable (the runtime's torch-only path never imports it).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def jacobi_sweeps(x, first, second, low, high, share_first, share_second, iterations,
                  plane_vertex, plane_point, plane_normal):
    """``iterations`` sweeps on (V,3) float32 positions ``x``, in place; returns ``x``.

    first, second: (E,) int64 edge ends; low, high: (E,) float32 the band of lengths;
    share_first, share_second: (E,) float32 the share of an edge's correction each end takes
    (inverse-mass weighted, averaged over the end's edges; the second's negative);
    plane_vertex (C,) int64, plane_point (C,3), plane_normal (C,3) float32: contact
    half-spaces enforced after every sweep (all gaps measured before any vertex moves, so a
    vertex with several planes gets the sum of their corrections, as ``ContactPlanes.project``).
    """
    edges, vertices, planes = first.shape[0], x.shape[0], plane_vertex.shape[0]
    moves = np.zeros((vertices, 3), np.float32)
    push = np.empty((planes, 3), np.float32)
    for _ in range(iterations):
        moves[:] = 0.0
        for e in range(edges):
            a, b = first[e], second[e]
            d0, d1, d2 = x[b, 0] - x[a, 0], x[b, 1] - x[a, 1], x[b, 2] - x[a, 2]
            length = max(np.sqrt(d0 * d0 + d1 * d1 + d2 * d2), np.float32(1e-12))
            if length > high[e]:
                scale = (length - high[e]) / length
            elif length < low[e]:
                scale = (length - low[e]) / length
            else:
                continue
            add_edge_move(moves, a, b, share_first[e] * scale, share_second[e] * scale, d0, d1, d2)
        apply_moves(x, moves)
        keep_outside_planes(x, plane_vertex, plane_point, plane_normal, push)
    return x


@numba.njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def rest_length_sweeps(x, first, second, rest, share_first, share_second, sweeps, plane_vertex, plane_point,
                       plane_normal):
    """``jacobi_sweeps`` without a band: every edge moves towards its (E,) ``rest`` length, so
    no branch per edge, and in fast-math (~0.08 ms a sweep at 5k vertices against ~0.23 for
    ``jacobi_sweeps``): the runtime's proxy sweeps. Same arguments otherwise."""
    edges, vertices = first.shape[0], x.shape[0]
    moves = np.zeros((vertices, 3), np.float32)
    push = np.empty((plane_vertex.shape[0], 3), np.float32)
    for _ in range(sweeps):
        moves[:] = 0.0
        for e in range(edges):
            a, b = first[e], second[e]
            d0, d1, d2 = x[b, 0] - x[a, 0], x[b, 1] - x[a, 1], x[b, 2] - x[a, 2]
            length = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            scale = (length - rest[e]) / max(length, np.float32(1e-12))
            add_edge_move(moves, a, b, share_first[e] * scale, share_second[e] * scale, d0, d1, d2)
        apply_moves(x, moves)
        keep_outside_planes(x, plane_vertex, plane_point, plane_normal, push)
    return x


@numba.njit(cache=True, nogil=True, inline="always")
def add_edge_move(moves, a, b, to_a, to_b, d0, d1, d2):
    """Add an edge's move to both ends' sums: ``to_a`` and ``to_b`` times its vector (d0, d1, d2)."""
    moves[a, 0] += to_a * d0
    moves[a, 1] += to_a * d1
    moves[a, 2] += to_a * d2
    moves[b, 0] += to_b * d0
    moves[b, 1] += to_b * d1
    moves[b, 2] += to_b * d2


@numba.njit(cache=True, nogil=True, inline="always")
def apply_moves(x, moves):
    """Add the (V,3) summed moves to the (V,3) positions, in place."""
    for v in range(x.shape[0]):
        x[v, 0] += moves[v, 0]
        x[v, 1] += moves[v, 1]
        x[v, 2] += moves[v, 2]


@numba.njit(cache=True, nogil=True, inline="always")
def keep_outside_planes(x, plane_vertex, plane_point, plane_normal, push):
    """Move each constrained vertex behind its half-space's plane onto it, in place; a vertex
    with several planes gets the sum of their corrections, each measured before any is applied
    (``ContactPlanes.project``); push: (C,3) float32 scratch."""
    planes = plane_vertex.shape[0]
    for c in range(planes):
        v = plane_vertex[c]
        gap = ((x[v, 0] - plane_point[c, 0]) * plane_normal[c, 0] + (x[v, 1] - plane_point[c, 1]) * plane_normal[c, 1]
               + (x[v, 2] - plane_point[c, 2]) * plane_normal[c, 2])
        depth = -gap if gap < 0.0 else np.float32(0.0)
        push[c, 0] = depth * plane_normal[c, 0]
        push[c, 1] = depth * plane_normal[c, 1]
        push[c, 2] = depth * plane_normal[c, 2]
    for c in range(planes):
        v = plane_vertex[c]
        x[v, 0] += push[c, 0]
        x[v, 1] += push[c, 1]
        x[v, 2] += push[c, 2]
