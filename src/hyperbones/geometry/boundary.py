"""The open borders of a garment mesh: its boundary loops (neck, sleeves, hem), in order.

A skirt's or dress's hem is its lowest loop; an ordered loop gives the area it encloses seen
from above, which tells a hem spanning between the legs from one wrapped around a leg.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph
import torch


def boundary_loops(faces: torch.Tensor) -> list[torch.Tensor]:
    """(F,3) triangles -> each closed border as (L,) vertex indices in order around it.

    A border edge belongs to one face only. Borders that are not simple cycles (a vertex
    where two borders touch) are walked as far as a depth-first order goes.
    """
    triangles = faces.detach().cpu().numpy()
    edges = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    border = unique[counts == 1]
    if len(border) == 0:
        return []
    size = int(triangles.max()) + 1
    graph = scipy.sparse.coo_matrix((np.ones(len(border)), (border[:, 0], border[:, 1])), shape=(size, size)).tocsr()
    on_border = np.zeros(size, dtype=bool)
    on_border[border.ravel()] = True
    _, component = scipy.sparse.csgraph.connected_components(graph, directed=False)
    loops = []
    for label in np.unique(component[on_border]):  # one per border: a handful a garment
        start = int(np.flatnonzero((component == label) & on_border)[0])
        order = scipy.sparse.csgraph.depth_first_order(graph, start, directed=False, return_predecessors=False)
        loops.append(torch.from_numpy(order.astype(np.int64)))
    return loops


def lowest_loop(faces: torch.Tensor, vertices: torch.Tensor) -> torch.Tensor | None:
    """(L,) the boundary loop of the mesh (``faces`` (F,3), ``vertices`` (V,3), Z up) whose
    vertices lie lowest on average: a skirt's or dress's hem; None for a closed mesh."""
    loops = boundary_loops(faces)
    if not loops:
        return None
    return min(loops, key=lambda loop: float(vertices[loop, 2].mean()))
