"""The preview camera: a fixed perspective view from a named direction, framed on the sequence's bounds."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def _view_basis(view: str, up_axis: str) -> tuple[np.ndarray, np.ndarray]:
    """(direction from the focal point to the camera, view-up) for a named view."""
    if up_axis == "y":
        table = {
            "front": ((0, 0, 1), (0, 1, 0)),
            "side": ((1, 0, 0), (0, 1, 0)),
            "top": ((0, 1, 0), (0, 0, -1)),
            "iso": ((1, 0.8, 1.4), (0, 1, 0)),
        }
    else:
        table = {
            "front": ((0, -1, 0), (0, 0, 1)),
            "side": ((1, 0, 0), (0, 0, 1)),
            "top": ((0, 0, 1), (0, 1, 0)),
            "iso": ((1, -1.4, 0.8), (0, 0, 1)),
        }
    d, u = (np.asarray(v, dtype=np.float64) for v in table[view])
    d /= np.linalg.norm(d)
    u = u - d * (u @ d)
    u /= np.linalg.norm(u)
    return d, u


@dataclass(frozen=True)
class CameraSetup:
    """A fixed perspective camera: position, focal point, view-up, view angle, clipping range, window shift."""

    position: tuple[float, float, float]
    focal_point: tuple[float, float, float]
    up: tuple[float, float, float]
    view_angle: float
    clipping: tuple[float, float]
    window_center: tuple[float, float]


def frame_camera(
    bounds: np.ndarray,
    view: str,
    size: tuple[int, int],
    up_axis: str = "y",
    view_angle: float = 30.0,
    margin: float = 0.1,
    reserve_right: float = 0.0,
    reserve_top: float = 0.0,
) -> CameraSetup:
    """A camera from `view` that shows the whole box `bounds` ((2, 3) min/max) tightly.

    The distance is the smallest at which every box corner is inside the view (perspective),
    less a margin; `reserve_right` (a fraction of the width) is kept free for a colour bar and
    `reserve_top` (a fraction of the height) for the frame label.
    """
    lo, hi = np.asarray(bounds[0], dtype=np.float64), np.asarray(bounds[1], dtype=np.float64)
    extent = np.maximum(hi - lo, 1e-9)
    center = (lo + hi) / 2
    d, u = _view_basis(view, up_axis)
    r = np.cross(u, d)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]) - center
    x, y, z = corners @ r, corners @ u, corners @ d
    tan_v = math.tan(math.radians(view_angle) / 2) * (1 - margin) * (1 - reserve_top)
    tan_h = math.tan(math.radians(view_angle) / 2) * size[0] / size[1] * (1 - margin) * (1 - reserve_right)
    distance = float(max(np.max(z + np.abs(x) / tan_h), np.max(z + np.abs(y) / tan_v), 1e-6))
    radius = float(np.linalg.norm(extent)) / 2
    near = max(distance - radius * 1.05, distance * 1e-3)
    far = distance + radius * 1.05
    position = center + d * distance
    return CameraSetup(
        position=tuple(position.tolist()),
        focal_point=tuple(center.tolist()),
        up=tuple(u.tolist()),
        view_angle=view_angle,
        clipping=(near, far),
        window_center=(reserve_right, reserve_top),
    )
