"""Batched forward kinematics with pytorch-kinematics.

Label definition (binding): joint i's position is the origin of the child link
frame of the i-th estimated joint; the base position is the origin of the base
link frame. :class:`Kinematics` returns both in the robot base frame, metres.
"""
from __future__ import annotations

import contextlib
import io
import xml.etree.ElementTree as ET

import numpy as np
import pytorch_kinematics as pk
import torch

from armpose.robots.registry import RobotSpec


def joint_child_links(urdf: bytes) -> dict[str, str]:
    """Map every URDF joint name to its child link name."""
    root = ET.fromstring(urdf)
    return {j.get("name"): j.find("child").get("link") for j in root.findall("joint")}


def kinematic_urdf(urdf: bytes) -> bytes:
    """The URDF without ``transmission`` and ``gazebo`` elements, which carry no kinematics
    and which pytorch-kinematics' parser rejects in some vendor files (e.g. xArm)."""
    root = ET.fromstring(urdf)
    for tag in ("transmission", "gazebo"):
        for el in root.findall(tag):
            root.remove(el)
    return ET.tostring(root)


def build_chain(urdf: bytes, dtype=torch.float64) -> pk.Chain:
    """``pk.build_chain_from_urdf`` on :func:`kinematic_urdf`, with the parser's chatter silenced."""
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        chain = pk.build_chain_from_urdf(kinematic_urdf(urdf))
    return chain.to(dtype=dtype)


class Kinematics:
    """Forward kinematics of one robot type, batched over configurations."""

    def __init__(self, spec: RobotSpec, dtype=torch.float64):
        urdf = spec.urdf_bytes()
        self.spec = spec
        self.dtype = dtype
        self.chain = build_chain(urdf, dtype)
        self.param_names = self.chain.get_joint_parameter_names()
        children = joint_child_links(urdf)
        unknown = [j for j in list(spec.joints) + list(spec.fixed_joints) if j not in children]
        if unknown:
            raise ValueError(f"robot {spec.name!r}: joints {unknown} are not in {spec.urdf_path()}")
        self.child_links = [children[j] for j in spec.joints]
        self._index = [self.param_names.index(j) for j in spec.joints]
        self._fixed = {self.param_names.index(j): v for j, v in spec.fixed_joints.items()
                       if j in self.param_names}

    def full_configuration(self, q: torch.Tensor) -> torch.Tensor:
        """Expand estimated-joint angles ``(N, J)`` to the chain's parameter vector ``(N, DOF)``."""
        th = torch.zeros(q.shape[0], len(self.param_names), dtype=self.dtype)
        th[:, self._index] = q.to(self.dtype)
        for i, v in self._fixed.items():
            th[:, i] = v
        return th

    def link_transforms(self, q) -> dict[str, torch.Tensor]:
        """Link frames ``(N, 4, 4)`` in the URDF root frame for joint angles ``q (N, J)`` in radians."""
        q = torch.as_tensor(np.asarray(q), dtype=self.dtype)
        fk = self.chain.forward_kinematics(self.full_configuration(q))
        return {name: tf.get_matrix() for name, tf in fk.items()}

    def root_T_base(self) -> np.ndarray:
        """The base link frame in the URDF root frame (4x4); independent of the joint angles."""
        q = torch.zeros(1, self.spec.num_joints, dtype=self.dtype)
        return self.link_transforms(q)[self.spec.base_link][0].numpy()

    def joint_positions(self, q) -> np.ndarray:
        """Joint positions ``(N, J, 3)`` in the base link frame, metres, for angles ``q (N, J)``."""
        tfs = self.link_transforms(q)
        base = tfs[self.spec.base_link]
        base_inv = torch.linalg.inv(base)
        pts = torch.stack([tfs[link][:, :, 3] for link in self.child_links], dim=1)  # (N, J, 4)
        return torch.einsum("nij,nkj->nki", base_inv, pts)[..., :3].numpy()


def skew(v: torch.Tensor) -> torch.Tensor:
    """Cross-product matrices ``(..., 3, 3)`` of vectors ``(..., 3)``."""
    z = torch.zeros_like(v[..., 0])
    return torch.stack([torch.stack([z, -v[..., 2], v[..., 1]], -1),
                        torch.stack([v[..., 2], z, -v[..., 0]], -1),
                        torch.stack([-v[..., 1], v[..., 0], z], -1)], -2)


def axis_angle_matrix(v: torch.Tensor) -> torch.Tensor:
    """Rotations ``(..., 3, 3)`` from axis-angle vectors ``(..., 3)`` (radians), smooth at zero:
    ``I + a [v]x + b [v]x^2`` with ``a = sin t / t``, ``b = (1 - cos t) / t^2`` (Taylor below 1e-4)."""
    t2 = (v * v).sum(-1)[..., None, None]
    small = t2 < 1e-8
    t = torch.sqrt(torch.where(small, torch.ones_like(t2), t2))
    a = torch.where(small, 1 - t2 / 6, torch.sin(t) / t)
    b = torch.where(small, 0.5 - t2 / 24, (1 - torch.cos(t)) / (t * t))
    K = skew(v)
    return torch.eye(3, dtype=v.dtype, device=v.device) + a * K + b * (K @ K)


class SerialChain:
    """The estimated joints of :class:`Kinematics` as one serial chain of constant transforms and
    revolute axes, for fast, ``torch.func``-friendly forward kinematics (the kinematic fit).

    Built from pytorch-kinematics itself: with ``C_i(q)`` the child link frame of joint ``i``,
    ``C_i(q) = C_{i-1}(q) A_i R(axis_i, q_i)``, where ``A_i = C_{i-1}(0)^-1 C_i(0)`` holds the fixed
    joints and the joint origin between them (``C_{-1}`` the URDF root) and ``axis_i`` is the
    joint's axis in its own frame. Valid when each estimated joint is revolute and lies below the
    one before it; tests check it against :meth:`Kinematics.joint_positions` for every robot."""

    def __init__(self, kin: Kinematics):
        names = list(kin.spec.joints)
        q0 = torch.zeros(1, len(names), dtype=kin.dtype)
        tfs = kin.link_transforms(q0)
        frames = [torch.eye(4, dtype=kin.dtype)] + [tfs[link][0] for link in kin.child_links]
        self.A = torch.stack([torch.linalg.inv(frames[i]) @ frames[i + 1] for i in range(len(names))])
        axes = []
        for name, link in zip(names, kin.child_links):
            joint = kin.chain.find_frame(link).joint
            if joint.joint_type != "revolute":
                raise ValueError(f"robot {kin.spec.name!r}: joint {name} is {joint.joint_type}, not revolute")
            axes.append(torch.as_tensor(joint.axis, dtype=kin.dtype))
        self.axes = torch.stack(axes)
        self.base_inv = torch.linalg.inv(tfs[kin.spec.base_link][0])

    def positions(self, q: torch.Tensor) -> torch.Tensor:
        """The base (origin) and every joint, ``(..., J + 1, 3)`` metres in the base link frame,
        for angles ``q`` ``(..., J)`` radians; differentiable, batch dimensions optional."""
        K = skew(self.axes / self.axes.norm(dim=-1, keepdim=True))           # unit axes: Rodrigues is exact
        KK = K @ K
        s, c = torch.sin(q)[..., None, None], torch.cos(q)[..., None, None]
        R = torch.eye(3, dtype=q.dtype) + s * K + (1 - c) * KK                 # (..., J, 3, 3)
        rot = self.base_inv[:3, :3].expand(*q.shape[:-1], 3, 3)
        pos = self.base_inv[:3, 3].expand(*q.shape[:-1], 3)
        out = [torch.zeros_like(pos)]
        for i in range(q.shape[-1]):
            pos = pos + rot @ self.A[i, :3, 3]
            rot = rot @ self.A[i, :3, :3] @ R[..., i, :, :]
            out.append(pos)
        return torch.stack(out, -2)
