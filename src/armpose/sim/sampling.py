"""Random robot configurations and camera poses for synthetic recordings."""
from __future__ import annotations

import numpy as np

from armpose.geometry import Camera, invert, look_at, transform_points
from armpose.sim.body import RobotBody


def collision_free_configuration(body: RobotBody, support: int, rng: np.random.Generator,
                                 max_tries: int = 500) -> np.ndarray:
    """Joint angles (radians) drawn uniformly over the joint limits, free of self-collision
    and of collision with ``support`` (table or floor). Leaves ``body`` in that configuration."""
    lim = np.array(body.spec.joint_limits)
    for _ in range(max_tries):
        q = rng.uniform(lim[:, 0], lim[:, 1])
        body.set_joints(q)
        if not body.in_collision([support]):
            return q
    raise RuntimeError(f"{body.spec.name}: no collision-free configuration in {max_tries} draws")


def sample_camera_pose(points_base: np.ndarray, camera: Camera, cfg: dict, rng: np.random.Generator,
                       max_tries: int = 50, margin_px: float = 4.0) -> np.ndarray:
    """``T_base_cam`` (4x4) of a camera around the robot, aimed near the centroid of ``points_base``
    (base and joints, metres, base frame). Distances, elevations (degrees), look-at jitter (metres)
    and roll (degrees, std) come from ``cfg`` (``params['render']['camera']``). Tries up to
    ``max_tries`` draws for one that sees every point inside the image; returns the last otherwise."""
    centre = points_base.mean(axis=0)
    T = np.eye(4)
    for _ in range(max_tries):
        dist = rng.uniform(*cfg["distance"])
        az = rng.uniform(0, 2 * np.pi)
        el = np.deg2rad(rng.uniform(*cfg["elevation_deg"]))
        target = centre + rng.normal(0, cfg["lookat_jitter"], 3)
        eye = target + dist * np.array([np.cos(az) * np.cos(el), np.sin(az) * np.cos(el), np.sin(el)])
        T = look_at(eye, target, roll=np.deg2rad(rng.normal(0, cfg["roll_std_deg"])))
        p_cam = transform_points(invert(T), points_base)
        uv = camera.project(p_cam)
        inside = ((p_cam[:, 2] > 0.1) & (uv[:, 0] >= margin_px) & (uv[:, 0] < camera.width - margin_px)
                  & (uv[:, 1] >= margin_px) & (uv[:, 1] < camera.height - margin_px))
        if inside.all():
            break
    return T
