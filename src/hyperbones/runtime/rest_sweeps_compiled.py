"""``RestLengthSweeps``' sweeps as one compiled loop (numba), for positions on the CPU.

Only ``runtime.rest_sweeps`` calls this, and only where numba imports (the torch-only path
runs its sparse products instead; the two agree to float32 rounding).
"""

from __future__ import annotations

import numba
import numpy as np

from hyperbones.physics.strain_sweeps import add_edge_move, apply_moves, keep_outside_planes


@numba.njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def rest_length_sweeps(x, first, second, rest, share_first, share_second, sweeps, plane_vertex, plane_point,
                       plane_normal):
    """``sweeps`` sweeps on (V,3) float32 positions ``x``, in place; returns ``x``.

    first, second: (E,) int64 edge ends; rest: (E,) float32 rest lengths; share_first,
    share_second: (E,) float32 each end's share of its edge's move (the second's negative);
    plane_vertex (C,) int64, plane_point (C,3), plane_normal (C,3) float32: half-spaces each
    constrained vertex is moved back into after every sweep. The strain limiter's loop
    (``physics.strain_sweeps``) without its band, in fast-math: its parts are shared.
    """
    edges, vertices = first.shape[0], x.shape[0]
    moves = np.zeros((vertices, 3), np.float32)
    push = np.empty((plane_vertex.shape[0], 3), np.float32)
    for _ in range(sweeps):
        moves[:] = 0.0
        for e in range(edges):
            a, b = first[e], second[e]
            d0, d1, d2 = x[b, 0] - x[a, 0], x[b, 1] - x[a, 1], x[b, 2] - x[a, 2]
            length = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            # No band to branch on: every edge moves towards its rest length.
            scale = (length - rest[e]) / max(length, np.float32(1e-12))
            add_edge_move(moves, a, b, share_first[e] * scale, share_second[e] * scale, d0, d1, d2)
        apply_moves(x, moves)
        keep_outside_planes(x, plane_vertex, plane_point, plane_normal, push)
    return x
