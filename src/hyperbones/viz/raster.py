"""Z-buffered triangle rasteriser and Lambert shading, compiled with numba.

Buffers shared by all kernels:
    rgb:  (H, W, 3) uint8 colour buffer, written in place.
    zbuf: (H, W) float64 view depth (distance along the camera axis), +inf = empty.
A pixel (row i, column j) is sampled at its centre (j + 0.5, i + 0.5).
Everything here is plain loops inside numba; callers stay in numpy.
"""

from __future__ import annotations

import math

import numba
import numpy as np

# Barycentric slack so that pixel centres on an edge shared by two triangles
# are never lost to rounding (a double hit is harmless: the z-test decides).
_EDGE_EPS = 1e-7


@numba.njit(cache=True, nogil=True)
def shade_mesh(vertices, faces, light_dir, ambient):
    """Lambert + ambient shade factors, both sides lit.

    vertices: (V, 3) float; faces: (F, 3) int; light_dir: (3,) unit vector
    pointing towards the light. Returns (vertex_shade (V,), face_shade (F,))
    float32 in [ambient, 1]. |n.l| is used so that back faces (the inside of
    a garment) are lit like front faces. Vertex normals are area-weighted
    sums of face normals.
    """
    n_v = vertices.shape[0]
    n_f = faces.shape[0]
    vnorm = np.zeros((n_v, 3), np.float64)
    face_shade = np.empty(n_f, np.float32)
    lx, ly, lz = light_dir[0], light_dir[1], light_dir[2]
    diffuse = 1.0 - ambient
    for f in range(n_f):
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        e1x = vertices[b, 0] - vertices[a, 0]
        e1y = vertices[b, 1] - vertices[a, 1]
        e1z = vertices[b, 2] - vertices[a, 2]
        e2x = vertices[c, 0] - vertices[a, 0]
        e2y = vertices[c, 1] - vertices[a, 1]
        e2z = vertices[c, 2] - vertices[a, 2]
        nx = e1y * e2z - e1z * e2y
        ny = e1z * e2x - e1x * e2z
        nz = e1x * e2y - e1y * e2x
        for k in range(3):
            v = faces[f, k]
            vnorm[v, 0] += nx
            vnorm[v, 1] += ny
            vnorm[v, 2] += nz
        length = math.sqrt(nx * nx + ny * ny + nz * nz)
        if length > 0.0:
            face_shade[f] = ambient + diffuse * abs(nx * lx + ny * ly + nz * lz) / length
        else:
            face_shade[f] = ambient
    vertex_shade = np.empty(n_v, np.float32)
    for v in range(n_v):
        nx, ny, nz = vnorm[v, 0], vnorm[v, 1], vnorm[v, 2]
        length = math.sqrt(nx * nx + ny * ny + nz * nz)
        if length > 0.0:
            vertex_shade[v] = ambient + diffuse * abs(nx * lx + ny * ly + nz * lz) / length
        else:
            vertex_shade[v] = ambient
    return vertex_shade, face_shade


@numba.njit(cache=True, nogil=True)
def rasterize(xy, depth, vertex_shade, face_shade, faces, color, smooth, near, rgb, zbuf):
    """Draw one mesh into rgb/zbuf.

    xy: (V, 2) float64 pixel coordinates; depth: (V,) float64 view depth;
    vertex_shade: (V,) and face_shade: (F,) shade factors (see shade_mesh);
    faces: (F, 3) int; color: (3,) float in [0, 1]; smooth: interpolate
    vertex_shade (True) or use face_shade (False). Triangles with a vertex
    closer than `near` (behind the camera) are skipped rather than clipped:
    the follow camera keeps the character metres away, so only stray geometry
    gets there. Triangles are drawn whatever their winding (no culling).
    """
    height, width = zbuf.shape
    for f in range(faces.shape[0]):
        i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
        z0, z1, z2 = depth[i0], depth[i1], depth[i2]
        if not (z0 > near and z1 > near and z2 > near):  # also rejects NaN
            continue
        x0, y0 = xy[i0, 0], xy[i0, 1]
        x1, y1 = xy[i1, 0], xy[i1, 1]
        x2, y2 = xy[i2, 0], xy[i2, 1]
        area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        if not abs(area) > 1e-12:  # degenerate (or NaN)
            continue
        # Pixel centres inside the bounding box, clamped in float first so that
        # huge coordinates of near-plane vertices cannot overflow the int cast.
        lo_x = max(min(x0, x1, x2) - 0.5, 0.0)
        hi_x = min(max(x0, x1, x2) - 0.5, width - 1.0)
        lo_y = max(min(y0, y1, y2) - 0.5, 0.0)
        hi_y = min(max(y0, y1, y2) - 0.5, height - 1.0)
        if lo_x > hi_x or lo_y > hi_y:
            continue
        col_lo, col_hi = int(math.ceil(lo_x)), int(math.floor(hi_x))
        row_lo, row_hi = int(math.ceil(lo_y)), int(math.floor(hi_y))
        inv_area = 1.0 / area
        # 1/z is affine in screen space, so interpolate it for a correct z-test.
        iz0, iz1, iz2 = 1.0 / z0, 1.0 / z1, 1.0 / z2
        if smooth:
            s0, s1, s2 = vertex_shade[i0], vertex_shade[i1], vertex_shade[i2]
        else:
            s0 = s1 = s2 = face_shade[f]
        for row in range(row_lo, row_hi + 1):
            py = row + 0.5
            for col in range(col_lo, col_hi + 1):
                px = col + 0.5
                w0 = ((x1 - px) * (y2 - py) - (x2 - px) * (y1 - py)) * inv_area
                if w0 < -_EDGE_EPS:
                    continue
                w1 = ((x2 - px) * (y0 - py) - (x0 - px) * (y2 - py)) * inv_area
                if w1 < -_EDGE_EPS:
                    continue
                w2 = 1.0 - w0 - w1
                if w2 < -_EDGE_EPS:
                    continue
                z = 1.0 / (w0 * iz0 + w1 * iz1 + w2 * iz2)
                if z >= zbuf[row, col]:
                    continue
                zbuf[row, col] = z
                s = (w0 * s0 + w1 * s1 + w2 * s2) * 255.0
                for c in range(3):
                    rgb[row, col, c] = np.uint8(min(color[c] * s + 0.5, 255.0))


@numba.njit(cache=True, nogil=True)
def splat_contact(vertices, origin, cell, reach, occlusion):
    """Accumulate a top-down contact-shadow map from vertices near the floor.

    vertices: (V, 3); origin: (2,) world xy of occlusion[0, 0]'s corner; cell:
    cell size (m); occlusion: (ny, nx) float32, updated in place with
    max(1 - z / reach) over vertices falling in each cell, so a foot resting
    on the floor casts a dark patch that fades as it lifts. Without it a
    floating foot looks the same as a planted one from a low camera.
    """
    ny, nx = occlusion.shape
    for v in range(vertices.shape[0]):
        z = vertices[v, 2]
        if not z < reach:
            continue
        i = int(math.floor((vertices[v, 1] - origin[1]) / cell))
        j = int(math.floor((vertices[v, 0] - origin[0]) / cell))
        if 0 <= i < ny and 0 <= j < nx:
            d = 1.0 - max(z, 0.0) / reach
            if d > occlusion[i, j]:
                occlusion[i, j] = d


@numba.njit(cache=True, nogil=True)
def _sample_bilinear(grid, x, y):
    """grid (ny, nx) sampled at continuous cell coordinates (x, y); zero outside."""
    ny, nx = grid.shape
    x0, y0 = int(math.floor(x)), int(math.floor(y))
    fx, fy = x - x0, y - y0
    total = 0.0
    for di in range(2):
        for dj in range(2):
            i, j = y0 + di, x0 + dj
            if 0 <= i < ny and 0 <= j < nx:
                total += grid[i, j] * (fy if di else 1.0 - fy) * (fx if dj else 1.0 - fx)
    return total


@numba.njit(cache=True, nogil=True)
def draw_ground(rgb, zbuf, eye, axes, focal, centre, tile, colors, fade_radius, near,
                occlusion, occ_origin, occ_cell, occ_strength):
    """Ray-cast the infinite plane z = 0 as a checkerboard, fading into rgb.

    eye: (3,) camera position; axes: (3, 3) rows right/up/forward; focal: pixels;
    centre: (2,) world xy the checkerboard fades around; tile: square size (m);
    colors: (2, 3) uint8-range tile colours; fade_radius: metres at which the
    floor has blended into the background; occlusion, occ_origin, occ_cell:
    contact-shadow map from splat_contact, darkening the floor by up to
    occ_strength. Exact per-pixel intersection (no triangles) means no
    near-plane clipping and no perspective distortion; the fade hides distant
    aliasing and the horizon.
    """
    height, width = zbuf.shape
    if eye[2] <= 0.0:  # below the floor: nothing sensible to draw
        return
    cx, cy = 0.5 * width, 0.5 * height
    occ_ny, occ_nx = occlusion.shape
    for row in range(height):
        dy = -(row + 0.5 - cy) / focal
        # rz is affine in dx, so checking both ends skips rows above the horizon.
        rz_left = axes[0, 2] * (0.5 - cx) / focal + axes[1, 2] * dy + axes[2, 2]
        rz_right = axes[0, 2] * (width - 0.5 - cx) / focal + axes[1, 2] * dy + axes[2, 2]
        if rz_left >= -1e-9 and rz_right >= -1e-9:
            continue
        for col in range(width):
            dx = (col + 0.5 - cx) / focal
            # Ray direction with unit forward component, so t is the view depth.
            rz = axes[0, 2] * dx + axes[1, 2] * dy + axes[2, 2]
            if rz >= -1e-9:
                continue
            t = -eye[2] / rz
            if t <= near or t >= zbuf[row, col]:
                continue
            wx = eye[0] + t * (axes[0, 0] * dx + axes[1, 0] * dy + axes[2, 0])
            wy = eye[1] + t * (axes[0, 1] * dx + axes[1, 1] * dy + axes[2, 1])
            dist = math.sqrt((wx - centre[0]) ** 2 + (wy - centre[1]) ** 2)
            alpha = 1.0 - dist / fade_radius
            if alpha <= 0.0:
                continue
            alpha = min(1.0, 1.6 * alpha)  # flat in the middle, soft at the rim
            k = (int(math.floor(wx / tile)) + int(math.floor(wy / tile))) & 1
            gx = (wx - occ_origin[0]) / occ_cell - 0.5
            gy = (wy - occ_origin[1]) / occ_cell - 0.5
            dark = 1.0
            if -1.0 < gx < occ_nx and -1.0 < gy < occ_ny:  # most of the floor is far from any foot
                dark -= occ_strength * min(_sample_bilinear(occlusion, gx, gy), 1.0)
            zbuf[row, col] = t
            for c in range(3):
                bg = float(rgb[row, col, c])
                rgb[row, col, c] = np.uint8(bg + alpha * (dark * colors[k, c] - bg) + 0.5)
