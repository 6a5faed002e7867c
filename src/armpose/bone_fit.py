"""Bone-length fit: each predicted point moved along its own ray so the skeleton has the robot's bones.

The network reads a joint's 2D position far better than its depth (README, "Where the joint
error comes from": slid along its ray to the true depth, a joint would be 3.5-5.1 cm off, against
11-20 cm as predicted). The distance between consecutive joint origins of a robot (base ->
joint 1 -> ... -> joint J) does not depend on its joint angles, so a skeleton whose points lie on
the predicted rays and whose bones have the robot's lengths is pinned down up to what the rays
cannot tell apart. Per frame, with ``p_i = z_i * ray_i`` (point 0 the base, then the joints;
``ray_i = p^_i / z^_i`` of the network's point ``p^_i``) the fit minimises over the depths ``z_i``

    sum_b ((|p_b - p_(b-1)| - L_b) / sigma_bone)^2 + sum_i ((log z_i - log z^_i) / sigma_depth)^2

``L_b`` are the bones of the frame's (predicted) robot type, ``sigma_bone`` (metres) how closely the
bones are held and ``sigma_depth`` (relative) how far a depth may leave the network's. Every 2D
position is kept exactly: only depths move. Solved globally on a grid by dynamic programming along the
chain, then refined by Levenberg-Marquardt in log depth; batched over frames, float64. Positions are metres in the camera optical frame (x right, y down, z forward).
"""
from __future__ import annotations

import numpy as np
import torch

from armpose.robots import get_robot
from armpose.robots.kinematics import Kinematics

MIN_DEPTH_M = 0.05      # network depths are clamped to this before the fit (points behind the camera)
_EPS_M = 1e-3           # smooths the bone length at zero (Panda has coincident joint origins)
SEARCH_HALF_RANGE = 0.5  # log depth: the grid search covers 0.61-1.65 x the network's depth
SEARCH_GRID = 101        # grid values per point (steps of 1 % in depth)
CHUNK = 256              # frames per grid search (memory: CHUNK x SEARCH_GRID^2 doubles)


def bone_lengths(robot: str) -> np.ndarray:
    """Distances (m) base -> joint 1 -> ... -> joint J of ``robot``, at any joint angles."""
    spec = get_robot(robot)
    joints = Kinematics(spec).joint_positions(np.zeros((1, spec.num_joints)))[0]
    return np.linalg.norm(np.diff(np.vstack([np.zeros(3), joints]), axis=0), axis=1)


def check_sigmas(sigma_depth: float, sigma_bone: float) -> None:
    """Both must be finite and positive; the error names the value."""
    for name, value in (("sigma_depth", sigma_depth), ("sigma_bone", sigma_bone)):
        if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
            raise ValueError(f"bone_fit.{name} must be a positive number, got {value!r}")


def _residuals(u, u_net, rays, L, w, sigma_depth, sigma_bone, jacobian: bool):
    """Stacked residuals (N, 2K-1) of the objective at log depths ``u`` (N, K), and their
    Jacobian (N, 2K-1, K) when asked."""
    q = torch.exp(u)[..., None] * rays                           # (N, K, 3)
    delta = q[:, 1:] - q[:, :-1]                                 # (N, K-1, 3)
    d = torch.sqrt((delta ** 2).sum(-1) + _EPS_M ** 2)
    r = torch.cat([w * (d - L) / sigma_bone, (u - u_net) / sigma_depth], dim=1)
    if not jacobian:
        return r, None
    n, k = u.shape
    jac = torch.zeros(n, 2 * k - 1, k, dtype=u.dtype)
    idx = torch.arange(k - 1)
    # d(d_b)/d(u_b) = delta_b . q_b / d_b ; d(d_b)/d(u_(b-1)) = -delta_b . q_(b-1) / d_b
    jac[:, idx, idx + 1] = w * (delta * q[:, 1:]).sum(-1) / d / sigma_bone
    jac[:, idx, idx] = -w * (delta * q[:, :-1]).sum(-1) / d / sigma_bone
    jac[:, k - 1 + torch.arange(k), torch.arange(k)] = 1.0 / sigma_depth
    return r, jac


def _chain_search(u_net, rays, L, w, sigma_depth, sigma_bone, half_range: float, grid: int) -> torch.Tensor:
    """The global minimum of the objective over log depths on a grid of ``grid`` values within
    ``half_range`` of each network depth: the bones couple consecutive points only, so dynamic
    programming along the chain (min-sum, O(K grid^2) per frame) finds it exactly. (N, K)."""
    offsets = torch.linspace(-half_range, half_range, grid, dtype=torch.float64)
    depth = torch.exp(u_net[..., None] + offsets)                      # (N, K, G)
    sq = (rays ** 2).sum(-1)                                           # (N, K)
    cos = (rays[:, 1:] * rays[:, :-1]).sum(-1)                         # (N, K-1)
    unary = (offsets / sigma_depth) ** 2                               # (G,)
    cost = unary.expand(len(u_net), grid).clone()
    back = []
    for b in range(1, u_net.shape[1]):
        a, c = depth[:, b - 1, :, None], depth[:, b, None, :]          # previous (rows), this (columns)
        d2 = a ** 2 * sq[:, b - 1, None, None] + c ** 2 * sq[:, b, None, None] - 2 * a * c * cos[:, b - 1, None, None]
        d = torch.sqrt(d2.clamp_min(0) + _EPS_M ** 2)
        pair = w[:, b - 1, None, None] * ((d - L[:, b - 1, None, None]) / sigma_bone) ** 2
        best, arg = (cost[:, :, None] + pair).min(dim=1)
        cost = best + unary
        back.append(arg)
    idx = cost.argmin(dim=1)
    picks = [idx]
    for arg in reversed(back):
        idx = arg.gather(1, idx[:, None])[:, 0]
        picks.append(idx)
    return u_net + offsets[torch.stack(picks[::-1], dim=1)]


def fit_depths(points: np.ndarray, bones: np.ndarray, bone_valid: np.ndarray, sigma_depth: float,
               sigma_bone: float = 0.01, iters: int = 20, search: bool = True) -> np.ndarray:
    """Move each of ``points`` (N, K, 3; point 0 the base, then the joints; metres, camera frame)
    along its ray so that point b lies ``bones[:, b-1]`` from point b-1 wherever
    ``bone_valid[:, b-1]`` (both (N, K-1)); a point no valid bone touches keeps its depth, and a
    non-finite point is returned as given (the bones touching it are not held).
    A grid search by dynamic programming along the chain (depths within a factor
    exp(+-``SEARCH_HALF_RANGE``) of the network's) finds the grid's best depths, near the global
    minimum, which a local method misses when a bone has to flip towards or away from the camera
    (``search`` False: start at the network's depths instead); then Levenberg-Marquardt in log
    depth, a damping per frame, ``iters`` iterations. Returns the moved points (N, K, 3); their
    projections equal those of ``points`` (depths below ``MIN_DEPTH_M`` are first raised to it)."""
    check_sigmas(sigma_depth, sigma_bone)
    points = np.asarray(points, np.float64)
    bones, bone_valid = np.asarray(bones, np.float64), np.asarray(bone_valid, bool)
    if points.ndim != 3 or points.shape[-1] != 3 or bones.shape != (len(points), points.shape[1] - 1) \
            or bone_valid.shape != bones.shape:
        raise ValueError(f"fit_depths: points {points.shape}, bones {bones.shape} and bone_valid "
                         f"{bone_valid.shape} do not match")
    finite = np.isfinite(points).all(-1)
    bone_valid = bone_valid & finite[:, 1:] & finite[:, :-1]
    p = torch.as_tensor(np.where(finite[..., None], points, [0.0, 0.0, 1.0]))
    z_net = p[..., 2].clamp_min(MIN_DEPTH_M)
    rays = p / z_net[..., None]
    rays[..., 2] = 1.0
    u_net = torch.log(z_net)
    args = (u_net, rays, torch.as_tensor(bones), torch.as_tensor(bone_valid, dtype=torch.float64),
            sigma_depth, sigma_bone)
    if search and len(u_net):
        u = torch.cat([_chain_search(u_net[i:i + CHUNK], rays[i:i + CHUNK], args[2][i:i + CHUNK], args[3][i:i + CHUNK],
                                     sigma_depth, sigma_bone, SEARCH_HALF_RANGE, SEARCH_GRID)
                       for i in range(0, len(u_net), CHUNK)])
    else:
        u = u_net.clone()
    damping = torch.full((len(u),), 1e-3, dtype=torch.float64)
    for _ in range(iters):
        r, jac = _residuals(u, *args, jacobian=True)
        cost = (r ** 2).sum(1)
        jt = jac.transpose(1, 2)
        hess = jt @ jac
        diag = torch.diag_embed(torch.diagonal(hess, dim1=1, dim2=2))
        step = torch.linalg.solve(hess + damping[:, None, None] * diag, (jt @ r[..., None]))[..., 0]
        trial = u - step
        better = (_residuals(trial, *args, jacobian=False)[0] ** 2).sum(1) < cost
        u = torch.where(better[:, None], trial, u)
        damping = torch.where(better, damping / 3, damping * 4).clamp(1e-9, 1e9)
    return np.where(finite[..., None], (torch.exp(u)[..., None] * rays).numpy(), points)


def bone_fit(joints: np.ndarray, base: np.ndarray, types: np.ndarray, robot_types: list[str],
             sigma_depth: float, sigma_bone: float = 0.01, min_bone: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Predicted ``joints`` (N, J, 3) and ``base`` (N, 3) after :func:`fit_depths` with the bones of
    each frame's robot type (``types`` (N,), indices into ``robot_types``); bones shorter than
    ``min_bone`` metres are not held (Panda's coincident joint origins: two rays that the network
    puts apart can only meet at the camera). Joint slots past a type's joint count are returned
    unchanged."""
    joints = np.asarray(joints, np.float64)
    n, slots = joints.shape[:2]
    L = np.zeros((n, slots))
    valid, used = np.zeros((n, slots), bool), np.zeros((n, slots), bool)
    table = [bone_lengths(name) for name in robot_types]
    for i, t in enumerate(np.asarray(types, np.int64)):
        m = min(len(table[t]), slots)
        L[i, :m] = table[t][:m]
        valid[i, :m] = table[t][:m] >= min_bone
        used[i, :m] = True
    fitted = fit_depths(np.concatenate([np.asarray(base, np.float64)[:, None], joints], axis=1), L, valid,
                        sigma_depth, sigma_bone)
    out = np.where(used[..., None], fitted[:, 1:], joints)
    return out, fitted[:, 0]
