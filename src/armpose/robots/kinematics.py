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
