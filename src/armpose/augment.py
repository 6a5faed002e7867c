"""Geometric augmentation with consistent 3D labels: a virtual turn and dolly of the camera.

Rotating a pinhole camera about its optical centre by ``R`` moves every camera-frame point to
``X' = R X`` and every pixel by the homography ``H = K R K^-1``, whatever the scene's depth;
so an image warped by ``H``, with its mask warped the same way and its joints and base
rotated by ``R``, is a true image of the same robot from a camera turned by ``R``, with
the same intrinsics ``K``. A horizontal mirror ``F = diag(-1, 1, 1)`` is exact in the same
way when the principal point is at the image centre (the mirrored robot is a mirror-image
robot whose joints are still where the labels say); it is skipped otherwise.

A dolly (the camera moved along its optical axis, towards or away from the robot) changes
the robot's apparent size with its distance, the cue the network reads depth from, and so
gives every rendered view new (size, depth) pairs. For a robot at depth ``z_ref`` (the mean
depth of its joints) moved to ``z_ref + d``, the image scales about the principal point by
``s = z_ref / (z_ref + d)``; that scaling is exact for points at ``z_ref`` only, so the labels
are made consistent with the scaled image instead: each point keeps its image ray scaled
by ``s`` and gets depth ``z + d``. The labelled robot is thereby stretched across the
optical axis by ``s (z + d) / z``, a factor within about 4 % of one for a robot
0.5 m deep at 1.2-3.5 m and ``|s - 1| <= 0.15``; the background is treated as if at
``z_ref`` too (no parallax).

Frames and units: camera optical frame (x right, y down, z forward), metres; intrinsics
``(fx, fy, cx, cy)`` in pixels of the image being warped; angles in degrees in the config.
Config keys (``params.yaml``, a training stage's ``augment``): ``flip`` (probability),
``rotate_deg`` (pan and tilt, each uniform in +-value), ``roll_deg`` (about the optical
axis, uniform in +-value) and ``dolly`` (image scale ``s`` log-uniform in
``[1 / (1 + dolly), 1 + dolly]``). All zero: no warp at all. The turn is applied first.
"""
from __future__ import annotations

import cv2
import numpy as np

GEOMETRIC_KEYS = ("flip", "rotate_deg", "roll_deg", "dolly")


def _axis_rotation(axis: int, degrees: float) -> np.ndarray:
    """3x3 rotation by ``degrees`` about camera axis ``axis`` (0 x, 1 y, 2 z)."""
    a = np.radians(degrees)
    c, s = np.cos(a), np.sin(a)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def intrinsic_matrix(intrinsics) -> np.ndarray:
    """3x3 ``K`` from ``(fx, fy, cx, cy)``."""
    fx, fy, cx, cy = (float(v) for v in intrinsics)
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def centred(intrinsics, width: int, tol_px: float = 0.5) -> bool:
    """Whether the principal point is on the image's vertical centre line, so a mirror is exact."""
    return abs(float(intrinsics[2]) - (width - 1) / 2.0) <= tol_px


def draw_rotation(rng: np.random.Generator, cfg: dict, intrinsics, width: int) -> np.ndarray | None:
    """The virtual camera turn ``M`` (3x3, a rotation, times the mirror when drawn), or None
    when the config asks for no geometric augmentation. Draws come from ``rng`` in a fixed order."""
    flip_p = float(cfg.get("flip", 0.0))
    pan_tilt, roll = float(cfg.get("rotate_deg", 0.0)), float(cfg.get("roll_deg", 0.0))
    if flip_p <= 0 and pan_tilt <= 0 and roll <= 0:
        return None
    flip = rng.uniform() < flip_p
    pan, tilt, spin = rng.uniform(-1, 1, 3) * np.array([pan_tilt, pan_tilt, roll])
    M = _axis_rotation(1, pan) @ _axis_rotation(0, tilt) @ _axis_rotation(2, spin)
    if flip and centred(intrinsics, width):
        M = np.diag([-1.0, 1.0, 1.0]) @ M
    return M


def draw_dolly(rng: np.random.Generator, cfg: dict) -> float | None:
    """The dolly's image scale ``s`` (> 1: the camera moves closer), log-uniform in
    ``[1 / (1 + dolly), 1 + dolly]``, or None when ``cfg`` has no ``dolly``. Draw it after
    :func:`draw_rotation` from the same generator."""
    amount = float(cfg.get("dolly", 0.0))
    if amount <= 0:
        return None
    return float(np.exp(rng.uniform(-1.0, 1.0) * np.log1p(amount)))


def warp(image: np.ndarray, mask: np.ndarray, M: np.ndarray, intrinsics,
         scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """``image`` (H, W, 3) and ``mask`` (H, W) as seen by the camera turned by ``M`` and then
    dollied to image scale ``scale``: warped by ``S K M K^-1``, ``S`` the scaling about the
    principal point (bilinear for the image, nearest for the mask); uncovered pixels are 0."""
    K = intrinsic_matrix(intrinsics)
    cx, cy = K[0, 2], K[1, 2]
    S = np.array([[scale, 0.0, (1 - scale) * cx], [0.0, scale, (1 - scale) * cy], [0.0, 0.0, 1.0]])
    H = S @ K @ M @ np.linalg.inv(K)
    size = (image.shape[1], image.shape[0])
    out = cv2.warpPerspective(image, H, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    out_mask = cv2.warpPerspective(mask, H, size, flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out, out_mask


def rotate_points(points: np.ndarray, M: np.ndarray) -> np.ndarray:
    """Camera-frame points ``(..., 3)`` (metres) in the turned camera's frame: ``M @ X``."""
    return np.asarray(points, np.float64) @ M.T


def dolly_points(points: np.ndarray, scale: float, z_ref: float) -> np.ndarray:
    """Camera-frame points ``(..., 3)`` (metres) after a dolly to image scale ``scale`` of a
    robot at depth ``z_ref``: depth ``z + d`` with ``d = z_ref (1 / scale - 1)``, image ray
    scaled by ``scale`` about the principal point. Points at depth <= 0 (unused joint slots)
    are returned unchanged."""
    p = np.array(points, np.float64)
    z = p[..., 2:3]
    d = float(z_ref) * (1.0 / float(scale) - 1.0)
    front = z > 1e-6
    lateral = np.where(front, float(scale) * (z + d) / np.where(front, z, 1.0), 1.0)
    return np.concatenate([p[..., :2] * lateral, np.where(front, z + d, z)], -1)
