"""Kinematic fit: the robot's own model, posed and placed, fitted to the network's estimate.

The network's 3D points are a free cloud: nothing keeps the bones at their lengths or the
joints on their axes, and most of their error is depth (the README's "Where the joint error
comes from"), while their image rays are good. The fit finds joint angles ``q`` (radians, the
robot description's joints) and a camera-from-base pose ``(R, t)`` whose forward kinematics
(:mod:`armpose.robots.kinematics`, the base and every joint, metres, camera optical frame)

* lie on the rays of the network's points (normalised image coordinates ``x/z, y/z``, to
  ``ray_sigma``), and
* near their depths (``log z``, to ``log_depth_sigma``).

No joint encoders and no calibration are used: the robot type is the network's, the model
its description's. The result is a physically valid robot: bone lengths and joint axes exact,
angles within their limits (a penalty outside them), plus the estimated joint angles and
camera pose as by-products.

Solver: the ``starts`` random configurations are each rigidly aligned to the network's points
(Kabsch); the ``hypotheses`` best are refined by Levenberg-Marquardt, batched over the frames of
one robot type (forward-difference Jacobians of :class:`armpose.robots.kinematics.SerialChain`,
all parameters in one batched call), first on the points (metres), then on the rays and
depths; each frame keeps its lowest-cost hypothesis. Frames and units: camera optical frame (x right, y down, z forward), metres,
radians.

Sigmas. ``ray_sigma`` is the network's median ray error; ``log_depth_sigma`` its median
log-depth error times the square root of the number of points, because a frame's depth errors
are nearly all one shared error (frame depth error against depth error in the results table),
so its points' depth terms carry about one measurement, not one each. ``depth_ratio`` is the
network's typical predicted over true depth: below 1 for the larger robots, which it places too
close (as if it pulled every robot's size towards the mean); the points are divided by it before
the fit, so the depth terms are centred on depths without that bias. A checkpoint trained with
``fit_sigmas: true`` carries all three per robot type, measured on held-out training frames
(:mod:`armpose.fit_sigmas`); :class:`FitSettings`' values are the fallback, about the UR
types' (``benchmarks/kinematic_fit_sigmas.py`` compares the two).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np
import torch

from armpose.robots import get_robot
from armpose.robots.kinematics import Kinematics, SerialChain, axis_angle_matrix

log = logging.getLogger(__name__)

LIMIT_SIGMA_RAD = 0.01   # angles beyond a joint limit cost as a ray error of ray_sigma per 0.01 rad


@dataclass(frozen=True)
class FitSettings:
    """Weights and solver settings of :func:`fit_robot` (see the module docstring)."""

    ray_sigma: float = 0.012
    log_depth_sigma: float = 0.18
    depth_ratio: float = 1.0      # the network's typical predicted over true depth: points are divided by it first
    starts: int = 128
    hypotheses: int = 4
    point_iters: int = 3
    ray_iters: int = 20
    seed: int = 0


def kabsch(A: torch.Tensor, B: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``(R, t)`` (B, 3, 3), (B, 3) minimising ``|R A + t - B|^2`` over point sets (B, N, 3)."""
    ca, cb = A.mean(1, keepdim=True), B.mean(1, keepdim=True)
    U, _, Vt = torch.linalg.svd((A - ca).transpose(1, 2) @ (B - cb))
    d = torch.sign(torch.linalg.det(Vt.transpose(1, 2) @ U.transpose(1, 2)))
    D = torch.diag_embed(torch.stack([torch.ones_like(d), torch.ones_like(d), d], -1))
    R = Vt.transpose(1, 2) @ D @ U.transpose(1, 2)
    return R, cb[:, 0] - (R @ ca[:, 0, :, None])[..., 0]


def vector_from_rotation(R: torch.Tensor) -> torch.Tensor:
    """Axis-angle vectors (B, 3) of rotations (B, 3, 3) with angles below pi."""
    cos = ((R.diagonal(dim1=1, dim2=2).sum(-1) - 1) / 2).clamp(-1 + 1e-9, 1 - 1e-9)
    theta = torch.acos(cos)
    w = torch.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], -1)
    return w * (theta / (2 * torch.sin(theta)))[:, None]


def initial_pose(chain: SerialChain, limits: torch.Tensor, target: torch.Tensor, starts: int,
                 seed: int, keep: int = 1, chunk: int = 256) -> torch.Tensor:
    """Parameters ``[q, rotation vector, t]`` (B, keep, J + 6) of the ``keep`` best of ``starts``
    random configurations (uniform within ``limits`` (J, 2), from ``seed``), each rigidly aligned
    to ``target`` (B, J + 1, 3); ``chunk`` frames at a time."""
    g = torch.Generator().manual_seed(int(seed))
    qs = limits[:, 0] + (limits[:, 1] - limits[:, 0]) * torch.rand(starts, len(limits), generator=g, dtype=target.dtype)
    shapes = chain.positions(qs)                                           # (S, N, 3)
    keep = min(int(keep), int(starts))
    out = []
    for tgt in target.split(chunk):
        b, n = tgt.shape[0], tgt.shape[1]
        A = shapes[None].expand(b, -1, -1, -1).reshape(b * starts, n, 3)
        B = tgt[:, None].expand(-1, starts, -1, -1).reshape(b * starts, n, 3)
        R, t = kabsch(A, B)
        cost = ((A @ R.transpose(1, 2) + t[:, None] - B) ** 2).sum((1, 2)).reshape(b, starts)
        best = (cost.topk(keep, dim=1, largest=False).indices + torch.arange(b)[:, None] * starts).flatten()
        out.append(torch.cat([qs[best % starts], vector_from_rotation(R[best]), t[best]], 1).reshape(b, keep, -1))
    return torch.cat(out)


def posed_points(chain: SerialChain, theta: torch.Tensor) -> torch.Tensor:
    """The base and joints (..., J + 1, 3), camera frame, of parameters ``[q, rotation vector, t]``."""
    j = chain.axes.shape[0]
    R = axis_angle_matrix(theta[..., j:j + 3])
    return chain.positions(theta[..., :j]) @ R.transpose(-1, -2) + theta[..., None, j + 3:]


def jacobian(residual, theta: torch.Tensor, data: tuple[torch.Tensor, ...], eps: float = 1e-6) -> torch.Tensor:
    """``d residual / d theta`` (B, M, P) by forward differences, all ``P + 1`` evaluations of the
    batched ``residual(theta (N, P), *data (N, ...)) -> (N, M)`` in one call."""
    b, n = theta.shape
    shifted = torch.cat([theta[:, None], theta[:, None] + eps * torch.eye(n, dtype=theta.dtype)], 1)   # (B, P + 1, P)
    rep = [d[:, None].expand(b, n + 1, *d.shape[1:]).reshape(b * (n + 1), *d.shape[1:]) for d in data]
    r = residual(shifted.reshape(b * (n + 1), n), *rep).reshape(b, n + 1, -1)
    return ((r[:, 1:] - r[:, :1]) / eps).transpose(1, 2)


def levenberg_marquardt(residual, theta: torch.Tensor, data: tuple[torch.Tensor, ...], iters: int,
                        damping: float = 1e-3) -> torch.Tensor:
    """``theta`` (B, P) after ``iters`` damped Gauss-Newton steps on the batched ``residual(theta,
    *data) -> (B, M)`` (``data`` (B, ...) each, per frame); one damping factor per frame, and a step
    is kept only where it lowers that frame's cost."""
    lam = torch.full((theta.shape[0], 1, 1), float(damping), dtype=theta.dtype)
    r = residual(theta, *data)
    cost = (r * r).sum(-1)
    for _ in range(int(iters)):
        J = jacobian(residual, theta, data)
        H = J.transpose(1, 2) @ J
        g = J.transpose(1, 2) @ r[..., None]
        diag = torch.diag_embed(H.diagonal(dim1=1, dim2=2).clamp(min=1e-9))
        new = theta + torch.linalg.solve(H + lam * diag, -g)[..., 0]
        r_new = residual(new, *data)
        c_new = (r_new * r_new).sum(-1)
        ok = torch.isfinite(c_new) & (c_new < cost)
        theta = torch.where(ok[:, None], new, theta)
        r = torch.where(ok[:, None], r_new, r)
        cost = torch.where(ok, c_new, cost)
        lam = torch.where(ok[:, None, None], lam / 3, lam * 4).clamp(1e-7, 1e7)
    return theta


def fit_robot(points: np.ndarray, robot: str, settings: FitSettings | None = None) -> dict:
    """The kinematic fit of robot type ``robot`` to the network's ``points`` (B, J + 1, 3): its
    base then its J joints, metres, camera frame. Returns numpy arrays: ``points`` (B, J + 1, 3)
    the fitted base and joints, ``q`` (B, J) radians, ``T_cam_base`` (B, 4, 4) and ``cost``
    (B,), the final weighted squared residual per frame. The points are first divided by
    ``settings.depth_ratio`` (a move along their rays), so that the depth terms are centred on
    depths without the network's typical bias."""
    st = settings or FitSettings()
    spec = get_robot(robot)
    target = torch.as_tensor(np.asarray(points, np.float64) / float(st.depth_ratio))   # along the rays
    if target.ndim != 3 or target.shape[1:] != (spec.num_joints + 1, 3):
        raise ValueError(f"fit_robot({robot!r}) needs points (B, {spec.num_joints + 1}, 3), got {tuple(target.shape)}")
    if not torch.isfinite(target).all():
        raise ValueError(f"fit_robot({robot!r}): the points hold non-finite values")
    chain = SerialChain(Kinematics(spec))
    limits = torch.tensor(spec.joint_limits, dtype=target.dtype)
    j = spec.num_joints
    k = max(1, int(st.hypotheses))
    theta = initial_pose(chain, limits, target, st.starts, st.seed, keep=k).flatten(0, 1)   # (B k, J + 6)
    target = target.repeat_interleave(k, 0)
    z_net = target[..., 2].clamp(min=0.05)
    ray_net = target[..., :2] / z_net[..., None]
    log_z_net = torch.log(z_net)

    def beyond_limits(q: torch.Tensor) -> torch.Tensor:
        return (torch.relu(q - limits[:, 1]) + torch.relu(limits[:, 0] - q)) / LIMIT_SIGMA_RAD

    def point_residual(th: torch.Tensor, tgt: torch.Tensor) -> torch.Tensor:
        return torch.cat([((posed_points(chain, th) - tgt) / st.ray_sigma).flatten(1), beyond_limits(th[:, :j])], 1)

    def ray_residual(th: torch.Tensor, rays: torch.Tensor, log_z: torch.Tensor) -> torch.Tensor:
        P = posed_points(chain, th)
        z = P[..., 2].clamp(min=0.05)
        r = (P[..., :2] / z[..., None] - rays) / st.ray_sigma
        return torch.cat([r.flatten(1), (torch.log(z) - log_z) / st.log_depth_sigma, beyond_limits(th[:, :j])], 1)

    theta = levenberg_marquardt(point_residual, theta, (target,), st.point_iters)
    theta = levenberg_marquardt(ray_residual, theta, (ray_net, log_z_net), st.ray_iters)
    r = ray_residual(theta, ray_net, log_z_net)
    pick = (r * r).sum(-1).reshape(-1, k).argmin(1) + torch.arange(len(r) // k) * k    # each frame's best hypothesis
    theta, r, target = theta[pick], r[pick], target[pick]
    P = posed_points(chain, theta)
    T = torch.eye(4, dtype=target.dtype).repeat(len(target), 1, 1)
    T[:, :3, :3], T[:, :3, 3] = axis_angle_matrix(theta[:, j:j + 3]), theta[:, j + 3:]
    return {"points": P.numpy(), "q": theta[:, :j].numpy(), "T_cam_base": T.numpy(), "cost": (r * r).sum(-1).numpy()}


def fit_predictions(joints: np.ndarray, base: np.ndarray, types: np.ndarray, robot_types: list[str],
                    settings: FitSettings | None = None, sigmas: dict | None = None) -> dict:
    """The kinematic fit of every frame's predicted type: ``joints`` (B, max_joints, 3), ``base``
    (B, 3), ``types`` (B,) class indices into ``robot_types``. Returns ``joints`` (B, max_joints,
    3) (unused slots as given), ``base`` (B, 3), ``q`` (B, max_joints) radians (NaN in unused
    slots), ``T_cam_base`` (B, 4, 4) and ``cost`` (B,). ``sigmas`` (robot type -> ``ray_sigma``,
    ``log_depth_sigma`` and, when measured, ``depth_ratio``; :mod:`armpose.fit_sigmas`) override
    ``settings`` per type."""
    joints, base, types = np.asarray(joints, np.float64), np.asarray(base, np.float64), np.asarray(types)
    out = {"joints": joints.copy(), "base": base.copy(), "q": np.full(joints.shape[:2], np.nan),
           "T_cam_base": np.tile(np.eye(4), (len(types), 1, 1)), "cost": np.zeros(len(types))}
    for k in np.unique(types):
        rows = np.flatnonzero(types == k)
        n = get_robot(robot_types[k]).num_joints
        st = settings or FitSettings()
        own = (sigmas or {}).get(robot_types[k])
        if own:
            st = replace(st, ray_sigma=float(own["ray_sigma"]), log_depth_sigma=float(own["log_depth_sigma"]),
                         depth_ratio=float(own.get("depth_ratio", st.depth_ratio)))
        fit = fit_robot(np.concatenate([base[rows, None], joints[rows, :n]], 1), robot_types[k], st)
        out["base"][rows], out["joints"][rows, :n] = fit["points"][:, 0], fit["points"][:, 1:]
        out["q"][rows, :n], out["T_cam_base"][rows], out["cost"][rows] = fit["q"], fit["T_cam_base"], fit["cost"]
        log.info("kinematic fit: %d %s frames, median cost %.2f", len(rows), robot_types[k], float(np.median(fit["cost"])))
    return out
