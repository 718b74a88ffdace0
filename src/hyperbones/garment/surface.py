"""Surfaces for garments: implicit solid -> surface -> plane cuts -> even triangles -> UV atlas."""

from __future__ import annotations

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph


def surface_from_field(field: np.ndarray, origin: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """Boundary of the solid ``field < 0`` (marching cubes), normals pointing out.

    Args:
        field: (X,Y,Z) samples, negative inside; origin: (3,) position of sample (0,0,0);
        voxel: spacing, metres.

    Returns:
        (N,3) float64 vertices, (M,3) int64 faces.
    """
    from skimage.measure import marching_cubes

    vertices, faces, _, _ = marching_cubes(field, level=0.0, spacing=(voxel,) * 3)
    return vertices + origin, faces.astype(np.int64)


def slice_mesh(vertices: np.ndarray, faces: np.ndarray, normal: np.ndarray, origin: np.ndarray,
               face_mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Cut a mesh with a plane, keeping the side ``normal`` points to (exact cut edges, no cap).

    Only the faces in ``face_mask`` are cut (the others are kept whole), so a sleeve's plane
    can end the sleeve without slicing through the torso.
    """
    from trimesh.intersections import slice_faces_plane

    normal, origin = np.asarray(normal, dtype=np.float64), np.asarray(origin, dtype=np.float64)
    if face_mask is None or face_mask.all():
        new_vertices, new_faces = slice_faces_plane(vertices, faces, normal, origin)[:2]
        return weld(np.asarray(new_vertices), np.asarray(new_faces, dtype=np.int64))
    if not face_mask.any():
        return vertices, faces
    cut_vertices, cut_faces = slice_faces_plane(vertices, faces[face_mask], normal, origin)[:2]
    merged = np.concatenate([vertices, np.asarray(cut_vertices)])
    merged_faces = np.concatenate([faces[~face_mask], np.asarray(cut_faces, dtype=np.int64) + len(vertices)])
    return weld(merged, merged_faces)


def weld(vertices: np.ndarray, faces: np.ndarray, tolerance: float = 1e-7) -> tuple[np.ndarray, np.ndarray]:
    """Merge coincident vertices, drop collapsed faces and unreferenced vertices."""
    keys = np.round(vertices / tolerance).astype(np.int64)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    faces = inverse.reshape(-1)[faces]
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])]
    used, compact = np.unique(faces, return_inverse=True)
    return vertices[first][used], compact.reshape(-1, 3).astype(np.int64)


def largest_piece(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The largest edge-connected piece (stray bits such as a grown hand are dropped)."""
    rows = np.concatenate([faces[:, 0], faces[:, 1], faces[:, 2]])
    cols = np.concatenate([faces[:, 1], faces[:, 2], faces[:, 0]])
    graph = scipy.sparse.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(vertices),) * 2)
    _, labels = scipy.sparse.csgraph.connected_components(graph, directed=False)
    face_labels = labels[faces[:, 0]]
    faces = faces[face_labels == np.bincount(face_labels).argmax()]
    used, compact = np.unique(faces, return_inverse=True)
    return vertices[used], compact.reshape(-1, 3).astype(np.int64)


def surface_area(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Total area, m²."""
    return float(_face_areas(vertices, faces).sum())


def isotropic_remesh(vertices: np.ndarray, faces: np.ndarray, target_vertices: int,
                     iterations: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Remesh to near-equilateral triangles with about ``target_vertices`` vertices (pymeshlab).

    Cloth energies are evaluated per triangle, so the slivers marching cubes and plane
    cuts leave would make the simulation stiff and uneven; open boundaries are kept.
    """
    import pymeshlab

    # An equilateral mesh with N vertices has about 2N triangles of area (sqrt(3)/4) L^2.
    length = float(np.sqrt(2.0 * surface_area(vertices, faces) / (np.sqrt(3.0) * target_vertices)))
    for _ in range(2):
        meshes = pymeshlab.MeshSet()
        meshes.add_mesh(pymeshlab.Mesh(vertex_matrix=vertices.astype(np.float64), face_matrix=faces.astype(np.int32)))
        meshes.meshing_isotropic_explicit_remeshing(iterations=iterations, targetlen=pymeshlab.PureValue(length),
                                                    checksurfdist=True, maxsurfdist=pymeshlab.PureValue(length / 4))
        mesh = meshes.current_mesh()
        count = mesh.vertex_number()
        if abs(count - target_vertices) <= 0.1 * target_vertices:
            break
        length *= float(np.sqrt(count / target_vertices))
    # Merge the ends of edges far shorter than the target (a cut's corner can leave one of
    # a fraction of a millimetre): such a sliver makes the cloth locally stiff.
    meshes.meshing_merge_close_vertices(threshold=pymeshlab.PureValue(0.2 * length))
    meshes.meshing_remove_null_faces()
    meshes.meshing_remove_duplicate_faces()
    mesh = meshes.current_mesh()
    vertices, faces = mesh.vertex_matrix().copy(), mesh.face_matrix().astype(np.int64)
    # A corner where two cuts meet can keep a sliver the remesher could not flip away; it
    # lies on the rim, so dropping it leaves the surface and its openings as they are.
    areas = _face_areas(vertices, faces)
    faces = faces[areas > 1e-4 * np.median(areas)]
    used, compact = np.unique(faces, return_inverse=True)
    return vertices[used], compact.reshape(-1, 3).astype(np.int64)


def _face_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    e1 = vertices[faces[:, 1]] - vertices[faces[:, 0]]
    e2 = vertices[faces[:, 2]] - vertices[faces[:, 0]]
    return 0.5 * np.linalg.norm(np.cross(e1, e2), axis=-1)


def uv_atlas(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """UV atlas with seams (xatlas).

    Returns:
        vertices (V,3) float32 (unchanged), faces (F,3) int64 (unchanged order),
        uvs (U,2) float32 in [0,1], face_uvs (F,3) int64 indices into uvs.
    """
    import xatlas

    mapping, uv_faces, uvs = xatlas.parametrize(vertices.astype(np.float32), faces.astype(np.uint32))
    if not np.array_equal(mapping[uv_faces], faces):
        raise RuntimeError("xatlas changed the face order")
    return vertices.astype(np.float32), faces.astype(np.int64), uvs.astype(np.float32), uv_faces.astype(np.int64)
