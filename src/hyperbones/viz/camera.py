"""Perspective look-at camera that follows the character (pure numpy).

Project conventions: metres, Z up, the body faces -Y. Camera space is
right-handed with x = right, y = up, z = forward (depth is positive in front of
the camera); image space has its origin at the top-left corner, u to the right,
v downwards, pixel (row i, column j) covering [j, j+1) x [i, i+1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

WORLD_UP = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class Camera:
    """A pinhole camera.

    eye, target: (3,) world positions; fov_y_deg: vertical field of view;
    near: points with view depth below this are treated as behind the camera.
    """

    eye: np.ndarray
    target: np.ndarray
    fov_y_deg: float = 40.0
    near: float = 0.05

    def axes(self) -> np.ndarray:
        """(3, 3) rotation whose rows are the camera's right, up and forward in world space."""
        return look_at(self.eye, self.target)

    def focal(self, height: int) -> float:
        """Focal length in pixels for an image `height` pixels tall."""
        return 0.5 * height / np.tan(np.radians(self.fov_y_deg) / 2.0)


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = WORLD_UP) -> np.ndarray:
    """(3, 3) rows = right, up, forward for a camera at `eye` looking at `target`."""
    forward = np.asarray(target, float) - np.asarray(eye, float)
    forward /= max(np.linalg.norm(forward), 1e-12)
    right = np.cross(forward, up)
    if np.linalg.norm(right) < 1e-6:  # looking straight up/down: any horizontal right will do
        right = np.cross(forward, np.array([0.0, 1.0, 0.0]))
    right /= np.linalg.norm(right)
    true_up = np.cross(right, forward)
    return np.stack([right, true_up, forward])


def project(camera: Camera, points: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Project world points to pixels.

    points: (N, 3). Returns xy (N, 2) float64 pixel coordinates (u right, v down)
    and depth (N,) float64 distance along the view axis. Points with depth <= near
    get meaningless xy; the rasteriser skips triangles that touch them.
    """
    rot = camera.axes()
    cam = (np.asarray(points, np.float64) - camera.eye) @ rot.T  # (N, 3) camera space
    depth = cam[:, 2]
    # Guard the division only; such points are discarded downstream anyway.
    safe = np.where(depth > camera.near, depth, camera.near)
    f = camera.focal(height)
    xy = np.empty((len(cam), 2))
    xy[:, 0] = 0.5 * width + f * cam[:, 0] / safe
    xy[:, 1] = 0.5 * height - f * cam[:, 1] / safe
    return xy, depth


def orbit_eye(target: np.ndarray, distance: float, azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """Eye position at `distance` from `target`.

    Azimuth 0 puts the camera straight in front of a body facing -Y; positive
    azimuth swings it towards the character's right (-X). Positive elevation
    raises it above the target.
    """
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    direction = np.array([-np.sin(az) * np.cos(el), -np.cos(az) * np.cos(el), np.sin(el)])
    return np.asarray(target, float) + distance * direction


def smooth_track(points: np.ndarray, fps: float, time_constant: float) -> np.ndarray:
    """Zero-lag low-pass filter of a trajectory.

    points: (T, 3). A first-order exponential filter run forwards then
    backwards, so the smoothed target neither lags behind a walking character
    nor jitters with every step. Returns (T, 3).
    """
    pts = np.asarray(points, np.float64)
    if time_constant <= 0 or len(pts) < 2:
        return pts.copy()
    alpha = 1.0 - np.exp(-1.0 / (fps * time_constant))
    out = pts.copy()
    for t in range(1, len(out)):  # T iterations of a 3-vector: cheap, not a per-pixel path
        out[t] = out[t - 1] + alpha * (out[t] - out[t - 1])
    for t in range(len(out) - 2, -1, -1):
        out[t] = out[t + 1] + alpha * (out[t] - out[t + 1])
    return out


def follow_cameras(
    bbox_min: np.ndarray,
    bbox_max: np.ndarray,
    fps: float,
    *,
    azimuth_deg: float = 30.0,
    elevation_deg: float = 10.0,
    fov_y_deg: float = 40.0,
    margin: float = 1.05,
    time_constant: float = 0.5,
) -> list[Camera]:
    """One camera per frame, following the character at a fixed distance.

    bbox_min, bbox_max: (T, 3) per-frame bounds of everything in the scene.
    The target is the low-pass filtered box centre; the distance is fixed for
    the whole sequence so that the largest frame's bounding sphere (times
    `margin`) fits the vertical field of view.
    """
    centres = 0.5 * (np.asarray(bbox_min, float) + np.asarray(bbox_max, float))
    radius = 0.5 * np.linalg.norm(np.asarray(bbox_max, float) - bbox_min, axis=1).max()
    radius = max(radius, 1e-3)
    distance = margin * radius / np.sin(np.radians(fov_y_deg) / 2.0)
    targets = smooth_track(centres, fps, time_constant)
    return [
        Camera(eye=orbit_eye(t, distance, azimuth_deg, elevation_deg), target=t, fov_y_deg=fov_y_deg)
        for t in targets
    ]
