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

A zoom (key ``zoom``, a mapping; off unless ``p`` > 0) is the view a second look at the robot
takes (:mod:`armpose.zoom_test`): with probability ``p`` the camera turns to look at the centre
of the robot's box (the projected base and valid joints; the centre shifted by a normal draw of
``centre_jitter`` box sizes) and dollies in until the box spans ``fill`` (uniform in the range)
of the image, scale clipped to ``[1 / (1 + dolly), max_zoom]`` and times ``exp(N(0,
scale_jitter))``. The random pan and tilt are not applied then (the jitter stands for them);
flip and roll are. The labels follow by :func:`rotate_points` and :func:`dolly_points`, the
same as a drawn turn and dolly, and :func:`undolly_points` and the transposed turn invert them,
which is how the second look's outputs are mapped back. Training with it puts the second look
in distribution.
"""
from __future__ import annotations

import cv2
import numpy as np

GEOMETRIC_KEYS = ("flip", "rotate_deg", "roll_deg", "dolly", "zoom")
ZOOM_DEFAULTS = {"p": 0.0, "fill": [0.45, 0.75], "max_zoom": 2.5, "centre_jitter": 0.1, "scale_jitter": 0.1}


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


def draw_rotation(rng: np.random.Generator, cfg: dict, intrinsics, width: int,
                  pan_tilt: bool = True) -> np.ndarray | None:
    """The virtual camera turn ``M`` (3x3, a rotation, times the mirror when drawn), or None
    when the config asks for no geometric augmentation. Draws come from ``rng`` in a fixed order,
    the same whether or not ``pan_tilt`` (False: the drawn pan and tilt are left out, for a zoom)."""
    flip_p = float(cfg.get("flip", 0.0))
    pan_tilt_deg, roll = float(cfg.get("rotate_deg", 0.0)), float(cfg.get("roll_deg", 0.0))
    if flip_p <= 0 and pan_tilt_deg <= 0 and roll <= 0:
        return None
    flip = rng.uniform() < flip_p
    pan, tilt, spin = rng.uniform(-1, 1, 3) * np.array([pan_tilt_deg, pan_tilt_deg, roll]) * [pan_tilt, pan_tilt, 1]
    M = _axis_rotation(1, pan) @ _axis_rotation(0, tilt) @ _axis_rotation(2, spin)
    if flip and centred(intrinsics, width):
        M = np.diag([-1.0, 1.0, 1.0]) @ M
    return M


def zoom_config(cfg: dict) -> dict | None:
    """The ``zoom`` settings of an ``augment`` config with defaults filled in, or None when off;
    a ValueError names a bad key or value."""
    zcfg = cfg.get("zoom")
    if not zcfg:
        return None
    if not isinstance(zcfg, dict):
        raise ValueError(f"augment.zoom must be a mapping, got {zcfg!r}")
    unknown = set(zcfg) - set(ZOOM_DEFAULTS)
    if unknown:
        raise ValueError(f"unknown augment.zoom keys {sorted(unknown)}; known: {sorted(ZOOM_DEFAULTS)}")
    out = {**ZOOM_DEFAULTS, **zcfg}
    lo, hi = (float(v) for v in out["fill"])
    if not (0 < lo <= hi <= 1) or not 0 <= float(out["p"]) <= 1 or not float(out["max_zoom"]) >= 1:
        raise ValueError(f"augment.zoom needs 0 <= p <= 1, 0 < fill[0] <= fill[1] <= 1, max_zoom >= 1; got {zcfg!r}")
    return out if float(out["p"]) > 0 else None


def points_box(points: np.ndarray, intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """``(centre, extent)`` pixels (2,) each: the axis-aligned box of camera-frame ``points``
    (N, 3), metres, projected through ``(fx, fy, cx, cy)``; points at depth <= 0 are ignored."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    p = p[p[:, 2] > 1e-6]
    if not len(p):
        raise ValueError("points_box needs at least one point in front of the camera")
    fx, fy, cx, cy = (float(v) for v in intrinsics)
    uv = np.stack([fx * p[:, 0] / p[:, 2] + cx, fy * p[:, 1] / p[:, 2] + cy], 1)
    lo, hi = uv.min(0), uv.max(0)
    return (lo + hi) / 2, hi - lo


def centring_turn(pixel, intrinsics) -> np.ndarray:
    """The camera turn ``M`` (3x3 rotation, ``X' = M X``) that puts the ray through ``pixel``
    (u, v) on the optical axis, without roll (the new x axis stays horizontal)."""
    fx, fy, cx, cy = (float(v) for v in intrinsics)
    z = np.array([(float(pixel[0]) - cx) / fx, (float(pixel[1]) - cy) / fy, 1.0])
    z /= np.linalg.norm(z)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z])


NEAREST_SHARE = 0.25   # after a dolly, the nearest point keeps at least this share of the robot's depth


def depth_limit(points: np.ndarray) -> float:
    """The largest dolly scale after which the nearest of ``points`` (N, 3; metres, camera frame)
    is still at :data:`NEAREST_SHARE` of the robot's new reference depth (the mean depth; see
    :func:`dolly_points`): a robot pointing at the camera is not dollied through it."""
    z = np.asarray(points, np.float64).reshape(-1, 3)[:, 2]
    z = z[z > 1e-6]
    gap = z.mean() - z.min()
    return float("inf") if gap <= 0 else float((1 - NEAREST_SHARE) * z.mean() / gap)


def zoom_scale(points: np.ndarray, intrinsics, size: tuple[int, int], fill: float, lo: float, hi: float) -> float:
    """The dolly's image scale that makes the box of ``points`` (N, 3; already turned) span
    ``fill`` of the image ``size`` = (width, height) in its larger proportion, clipped to [lo, hi]
    and to :func:`depth_limit`."""
    _, extent = points_box(points, intrinsics)
    frac = max(extent[0] / size[0], extent[1] / size[1], 1e-3)
    return float(np.clip(fill / frac, lo, max(lo, min(hi, depth_limit(points)))))


def draw_zoom(rng: np.random.Generator, cfg: dict, points: np.ndarray, intrinsics,
              size: tuple[int, int]) -> tuple[np.ndarray, dict] | None:
    """``(M_centre, zcfg)`` for a zoom drawn with probability ``zoom.p``: the turn that centres the
    (jittered) box of ``points`` (N, 3, camera frame, the robot's base and valid joints), or
    None. Draw it after :func:`draw_rotation` and :func:`draw_dolly`; then :func:`draw_zoom_scale`."""
    zcfg = zoom_config(cfg)
    if zcfg is None:
        return None
    take, shift = rng.uniform(), rng.normal(0.0, float(zcfg["centre_jitter"]), 2)
    if take >= float(zcfg["p"]):
        return None
    centre, extent = points_box(points, intrinsics)
    return centring_turn(centre + shift * extent.max(), intrinsics), zcfg


def draw_zoom_scale(rng: np.random.Generator, zcfg: dict, points_turned: np.ndarray, intrinsics,
                    size: tuple[int, int], dolly: float) -> float:
    """The zoom's image scale for ``points_turned`` (the points after the whole turn): the box
    spans a ``fill`` drawn uniformly, times ``exp(N(0, scale_jitter))``, within ``[1 / (1 +
    dolly), max_zoom]``."""
    fill, jitter = rng.uniform(*[float(v) for v in zcfg["fill"]]), rng.normal(0.0, float(zcfg["scale_jitter"]))
    lo, hi = 1.0 / (1.0 + float(dolly)), min(float(zcfg["max_zoom"]), depth_limit(points_turned))
    return float(np.clip(zoom_scale(points_turned, intrinsics, size, fill, 0.0, np.inf) * np.exp(jitter), lo, max(lo, hi)))


def draw_dolly(rng: np.random.Generator, cfg: dict) -> float | None:
    """The dolly's image scale ``s`` (> 1: the camera moves closer), log-uniform in
    ``[1 / (1 + dolly), 1 + dolly]``, or None when ``cfg`` has no ``dolly``. Draw it after
    :func:`draw_rotation` from the same generator."""
    amount = float(cfg.get("dolly", 0.0))
    if amount <= 0:
        return None
    return float(np.exp(rng.uniform(-1.0, 1.0) * np.log1p(amount)))


def view_homography(M: np.ndarray, intrinsics, scale: float = 1.0) -> np.ndarray:
    """``H = S K M K^-1`` (3x3): pixel ``p`` of the original image is pixel ``H p`` of the view
    from the camera turned by ``M`` and dollied to image scale ``scale`` (``S`` scales about
    the principal point)."""
    K = intrinsic_matrix(intrinsics)
    cx, cy = K[0, 2], K[1, 2]
    S = np.array([[scale, 0.0, (1 - scale) * cx], [0.0, scale, (1 - scale) * cy], [0.0, 0.0, 1.0]])
    return S @ K @ M @ np.linalg.inv(K)


def warp(image: np.ndarray, mask: np.ndarray, M: np.ndarray, intrinsics,
         scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """``image`` (H, W, 3) and ``mask`` (H, W) as seen by the camera turned by ``M`` and then
    dollied to image scale ``scale``: warped by :func:`view_homography` (bilinear for the
    image, nearest for the mask); uncovered pixels are 0."""
    H = view_homography(M, intrinsics, scale)
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


def undolly_points(points: np.ndarray, scale: float, z_ref_after: float) -> np.ndarray:
    """The inverse of :func:`dolly_points`: camera-frame points ``(..., 3)`` (metres) before a
    dolly to image scale ``scale``, given ``z_ref_after``, the robot's reference depth *after*
    it (``z_ref / scale``; at inference, the mean depth of the predicted joints). Points at
    depth <= 0 are returned unchanged."""
    p = np.array(points, np.float64)
    z = p[..., 2:3]
    d = float(z_ref_after) * (1.0 - float(scale))      # = z_ref (1 / scale - 1) with z_ref = scale z_ref_after
    front = z > 1e-6
    lateral = np.where(front, (z - d) / (float(scale) * np.where(front, z, 1.0)), 1.0)
    return np.concatenate([p[..., :2] * lateral, np.where(front, z - d, z)], -1)
