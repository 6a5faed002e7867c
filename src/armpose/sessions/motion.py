"""Smooth motion for simulated recording sessions: the robot's programmed moves and an operator's
handheld camera (:mod:`armpose.sessions.session`).

Frames and units: the robot base frame (z up, metres), joint angles in radians, time in seconds,
``T_base_cam`` the OpenCV optical frame (x right, y down, z forward) in the base frame. Every
random draw comes from the ``numpy`` generator passed in.
"""
from __future__ import annotations

import logging

import cv2
import numpy as np
from scipy.ndimage import gaussian_filter1d

from armpose.geometry import Camera, invert, look_at, transform_points
from armpose.sim.body import RobotBody
from armpose.sim.sampling import collision_free_configuration

log = logging.getLogger(__name__)

SLOW_HZ = (0.05, 0.2)  # frequencies of the operator's slow changes of distance, height, aim, roll
MIN_JERK_PEAK = 1.875  # peak speed of a minimum-jerk move over its mean speed


# --------------------------------------------------------------------------- robot motion

def min_jerk(tau: np.ndarray) -> np.ndarray:
    """Minimum-jerk progress 0 -> 1 for ``tau`` in [0, 1]: zero speed and acceleration at both ends."""
    return tau ** 3 * (10.0 - 15.0 * tau + 6.0 * tau ** 2)


def _collides(body: RobotBody, support: int, q: np.ndarray) -> bool:
    body.set_joints(q)
    return body.in_collision([support])


def _segment(body: RobotBody, support: int, rng: np.random.Generator, q0: np.ndarray, fps: float,
             cfg: dict, max_tries: int = 50) -> np.ndarray:
    """Joint angles ``(m, J)`` of one move from ``q0`` (excluded) to a random waypoint, collision-free
    at every frame, with peak joint speed at most ``cfg['max_joint_speed']`` rad/s; the robot holds
    still for the segment when no such waypoint is found."""
    lim = np.array(body.spec.joint_limits)
    duration = rng.uniform(*cfg["segment_s"])
    m = max(2, round(duration * fps))
    step = cfg["max_joint_speed"] * duration / MIN_JERK_PEAK
    tau = min_jerk(np.arange(1, m + 1) / m)[:, None]
    for _ in range(max_tries):
        q1 = np.clip(q0 + rng.uniform(-step, step, len(q0)), lim[:, 0], lim[:, 1])
        path = q0 + tau * (q1 - q0)
        if not any(_collides(body, support, q) for q in path):
            return path
    log.info("%s: no collision-free waypoint in %d draws, holding still", body.spec.name, max_tries)
    return np.repeat(q0[None], m, axis=0)


def robot_motion(body: RobotBody, support: int, rng: np.random.Generator, n: int, fps: float,
                 cfg: dict) -> np.ndarray:
    """Joint angles ``(n, J)`` (radians) at ``fps`` frames/s: from a collision-free configuration
    (:func:`~armpose.sim.sampling.collision_free_configuration`), minimum-jerk moves of
    ``cfg['segment_s']`` seconds to waypoints within the joint limits, each frame free of
    self-collision and of collision with ``support``. ``cfg`` is ``params['record']['robot']``."""
    path = [collision_free_configuration(body, support, rng)[None]]
    while sum(len(p) for p in path) < n:
        path.append(_segment(body, support, rng, path[-1][-1], fps, cfg))
    return np.concatenate(path)[:n]


# --------------------------------------------------------------------------- camera motion

def _wave(rng: np.random.Generator, t: np.ndarray, amplitude: float, hz) -> np.ndarray:
    """``amplitude * sin(2 pi f t + phase)``, random frequency ``f`` in ``hz`` and random phase."""
    return amplitude * np.sin(2 * np.pi * rng.uniform(*hz) * t + rng.uniform(0, 2 * np.pi))


def in_view(points_base: np.ndarray, T_base_cam: np.ndarray, camera: Camera, margin_px: float = 4.0) -> np.ndarray:
    """Boolean ``(n,)``: every point of frame i (``points_base (n, K, 3)``, base frame, metres) is in
    front of camera ``T_base_cam[i]`` and inside its image, ``margin_px`` from the border."""
    p = transform_points(invert(T_base_cam), points_base)
    uv = camera.project(p)
    ok = ((p[..., 2] > 0.1) & (uv[..., 0] >= margin_px) & (uv[..., 0] < camera.width - margin_px)
          & (uv[..., 1] >= margin_px) & (uv[..., 1] < camera.height - margin_px))
    return ok.all(axis=-1)


def fit_distance(points_base: np.ndarray, camera: Camera, fill: float = 0.9) -> float:
    """Distance (m) from the points' centre at which a sphere around all of them spans ``fill`` of
    the image's smaller half field of view."""
    pts = points_base.reshape(-1, 3)
    radius = float(np.linalg.norm(pts - pts.mean(axis=0), axis=1).max())
    half = min(np.arctan((camera.cx + 0.5) / camera.fx), np.arctan((camera.cy + 0.5) / camera.fy))
    return radius / (fill * np.tan(half))


def _rotvec(v: np.ndarray) -> np.ndarray:
    return cv2.Rodrigues(np.asarray(v, np.float64).reshape(3))[0]


def camera_orbit(points_base: np.ndarray, camera: Camera, cfg: dict, rng: np.random.Generator, fps: float,
                 floor_z: float = 0.0) -> np.ndarray:
    """``T_base_cam (n, 4, 4)`` of an operator walking around the robot with a handheld camera.

    ``points_base (n, K, 3)`` are the robot's base and joints per frame. The eye walks around the
    session's robot centre at ``cfg['walk_speed']`` m/s (random direction), at a distance within
    ``cfg['distance']`` (at least :func:`fit_distance`) and an elevation within
    ``cfg['elevation_deg']`` (eye at most ``cfg['max_height']`` above the floor at ``floor_z``),
    which drift slowly; the aim follows the robot's centroid (Gaussian smoothing of
    ``cfg['follow_s']`` s) with ``cfg['lookat_jitter']`` m drift; roll drifts within
    ``cfg['roll_deg']``; hand shake adds ``cfg['shake']`` (translation mm, rotation deg at ``hz``).
    Every term is a smooth function of time, so position and orientation are smooth.
    """
    n = len(points_base)
    t = np.arange(n) / fps
    centre = points_base.reshape(-1, 3).mean(axis=0)
    aim = gaussian_filter1d(points_base.mean(axis=1), sigma=max(cfg["follow_s"] * fps, 1e-3), axis=0, mode="nearest")
    aim = aim + np.stack([_wave(rng, t, cfg["lookat_jitter"], SLOW_HZ) for _ in range(3)], axis=1)
    lo, hi = cfg["distance"]
    lo = min(max(lo, fit_distance(points_base, camera)), hi)
    d_mid = rng.uniform(lo, hi)
    dist = d_mid + _wave(rng, t, min(d_mid - lo, hi - d_mid, 0.3), SLOW_HZ)
    top = np.degrees(np.arcsin(np.clip((floor_z + cfg["max_height"] - centre[2]) / dist.max(), -1.0, 1.0)))
    el_lo, el_hi = cfg["elevation_deg"][0], min(cfg["elevation_deg"][1], top)
    el_lo = min(el_lo, el_hi)
    el_mid = rng.uniform(el_lo, el_hi)
    el = np.radians(el_mid + _wave(rng, t, min(el_mid - el_lo, el_hi - el_mid, 6.0), SLOW_HZ))
    rate = rng.choice([-1.0, 1.0]) * rng.uniform(*cfg["walk_speed"]) / (d_mid * np.cos(np.radians(el_mid)))
    az = rng.uniform(0, 2 * np.pi) + rate * t + _wave(rng, t, np.radians(3.0), SLOW_HZ)
    eye = centre + dist[:, None] * np.stack([np.cos(az) * np.cos(el), np.sin(az) * np.cos(el), np.sin(el)], axis=1)
    shake = cfg["shake"]
    eye += np.stack([_wave(rng, t, shake["translation_mm"] / 1000.0, shake["hz"]) for _ in range(3)], axis=1)
    wobble = np.stack([_wave(rng, t, np.radians(shake["rotation_deg"]), shake["hz"]) for _ in range(3)], axis=1)
    roll = _wave(rng, t, np.radians(cfg["roll_deg"]), SLOW_HZ)
    out = np.empty((n, 4, 4))
    for i in range(n):
        out[i] = look_at(eye[i], aim[i], roll=roll[i])
        out[i, :3, :3] = out[i, :3, :3] @ _rotvec(wobble[i])
    return out


def handheld_camera(points_base: np.ndarray, camera: Camera, cfg: dict, rng: np.random.Generator, fps: float,
                    floor_z: float = 0.0, max_tries: int = 20) -> tuple[np.ndarray, float]:
    """A :func:`camera_orbit` in which at least ``cfg['min_in_view']`` of the frames see the base and
    every joint inside the image (the best of ``max_tries`` draws otherwise), and that fraction."""
    return _best_draw(lambda: camera_orbit(points_base, camera, cfg, rng, fps, floor_z), points_base, camera,
                      cfg["min_in_view"], max_tries, "handheld")


def _best_draw(draw, points_base: np.ndarray, camera: Camera, min_in_view: float, max_tries: int,
               kind: str) -> tuple[np.ndarray, float]:
    """The first camera path ``draw()`` (``T_base_cam (n, 4, 4)``) in which at least ``min_in_view``
    of the frames see the base and every joint, else the best of ``max_tries`` draws; and that fraction."""
    best, best_frac = None, -1.0
    for _ in range(max_tries):
        T = draw()
        frac = float(in_view(points_base, T, camera).mean())
        if frac > best_frac:
            best, best_frac = T, frac
        if frac >= min_in_view:
            break
    if best_frac < min_in_view:
        log.warning("%s: robot fully in view in only %.0f %% of the frames", kind, 100 * best_frac)
    return best, best_frac


def tripod_pose(points_base: np.ndarray, camera: Camera, cfg: dict, rng: np.random.Generator,
                floor_z: float = 0.0) -> np.ndarray:
    """One ``T_base_cam (4, 4)`` of a camera on a tripod looking at the session's robot centre.

    ``points_base (n, K, 3)`` are the robot's base and joints per frame (base frame, metres). The
    eye is at a random azimuth, a distance within ``cfg['distance']`` (at least
    :func:`fit_distance` of all frames' points) and an elevation within ``cfg['elevation_deg']``
    (eye at most ``cfg['max_height']`` above the floor at ``floor_z``); no roll, no drift, no shake.
    """
    centre = points_base.reshape(-1, 3).mean(axis=0)
    lo, hi = cfg["distance"]
    lo = min(max(lo, fit_distance(points_base, camera)), hi)
    dist = rng.uniform(lo, hi)
    top = np.degrees(np.arcsin(np.clip((floor_z + cfg["max_height"] - centre[2]) / dist, -1.0, 1.0)))
    el_hi = min(cfg["elevation_deg"][1], top)
    el = np.radians(rng.uniform(min(cfg["elevation_deg"][0], el_hi), el_hi))
    az = rng.uniform(0, 2 * np.pi)
    eye = centre + dist * np.array([np.cos(az) * np.cos(el), np.sin(az) * np.cos(el), np.sin(el)])
    return look_at(eye, centre)


def tripod_camera(points_base: np.ndarray, camera: Camera, cfg: dict, rng: np.random.Generator,
                  floor_z: float = 0.0, max_tries: int = 20) -> tuple[np.ndarray, float]:
    """A static camera ``T_base_cam (n, 4, 4)`` (one :func:`tripod_pose` repeated for every frame)
    in which at least ``cfg['min_in_view']`` of the frames see the base and every joint (the best
    of ``max_tries`` draws otherwise), and that fraction. The calibration-free use case: the
    camera stands still while the robot moves."""
    n = len(points_base)
    return _best_draw(lambda: np.repeat(tripod_pose(points_base, camera, cfg, rng, floor_z)[None], n, axis=0),
                      points_base, camera, cfg["min_in_view"], max_tries, "tripod")
