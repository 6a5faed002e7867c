"""A robot loaded into a PyBullet client: appearance, joint angles, link frames, collisions.

The robot's base link frame is placed at the world origin, so world = robot base frame.
"""
from __future__ import annotations

import numpy as np
import pybullet as pb

from armpose.geometry import invert, matrix_to_quat, pose_to_matrix
from armpose.robots.kinematics import Kinematics
from armpose.robots.registry import RobotSpec

SELF_COLLISION_FLAGS = pb.URDF_USE_SELF_COLLISION | pb.URDF_USE_SELF_COLLISION_EXCLUDE_ALL_PARENTS


class RobotBody:
    """One robot instance in PyBullet client ``client``.

    Visual meshes are the simplified ones of :meth:`RobotSpec.render_urdf_path` unless
    ``full_meshes``; collision meshes are always the URDF's own."""

    def __init__(self, client: int, spec: RobotSpec, kin: Kinematics | None = None,
                 T_world_base: np.ndarray | None = None, self_collision: bool = False, full_meshes: bool = False):
        self.client, self.spec = client, spec
        kin = kin or Kinematics(spec)
        self._root_T_base = kin.root_T_base()
        T_world_root = (np.eye(4) if T_world_base is None else T_world_base) @ invert(self._root_T_base)
        flags = pb.URDF_ENABLE_CACHED_GRAPHICS_SHAPES | (SELF_COLLISION_FLAGS if self_collision else 0)
        urdf = spec.urdf_path() if full_meshes else spec.render_urdf_path()
        self.id = pb.loadURDF(str(urdf), T_world_root[:3, 3].tolist(),
                              matrix_to_quat(T_world_root[:3, :3]).tolist(), useFixedBase=True,
                              flags=flags, physicsClientId=client)
        n = pb.getNumJoints(self.id, physicsClientId=client)
        infos = [pb.getJointInfo(self.id, i, physicsClientId=client) for i in range(n)]
        self.joint_index = {info[1].decode(): i for i, info in enumerate(infos)}
        self.link_index = {info[12].decode(): i for i, info in enumerate(infos)}
        self.link_index[pb.getBodyInfo(self.id, physicsClientId=client)[0].decode()] = -1
        self.parent_index = {i: info[16] for i, info in enumerate(infos)}
        self.movable = [self._is_movable(i, infos) for i in range(n)]
        self._estimated = [self.joint_index[j] for j in spec.joints]
        for name, value in spec.fixed_joints.items():
            pb.resetJointState(self.id, self.joint_index[name], value, physicsClientId=client)

    def place(self, T_world_base: np.ndarray) -> None:
        """Move the robot so that its base link frame has world pose ``T_world_base``."""
        T = T_world_base @ invert(self._root_T_base)
        dyn = pb.getDynamicsInfo(self.id, -1, physicsClientId=self.client)
        T_com = T @ pose_to_matrix(np.array(dyn[3]), np.array(dyn[4]))
        pb.resetBasePositionAndOrientation(self.id, T_com[:3, 3].tolist(), matrix_to_quat(T_com[:3, :3]).tolist(),
                                          physicsClientId=self.client)

    @staticmethod
    def _is_movable(i: int, infos) -> bool:
        """True if some non-fixed joint lies between link ``i`` and the root."""
        while i >= 0:
            if infos[i][2] != pb.JOINT_FIXED:
                return True
            i = infos[i][16]
        return False

    def set_colors(self, default, link_colors: dict) -> None:
        """Recolour links (RGBA in [0, 1]); ``default`` None keeps the meshes' own colours."""
        for link, idx in self.link_index.items():
            color = link_colors.get(link, default)
            if color is not None:
                pb.changeVisualShape(self.id, idx, rgbaColor=list(color), physicsClientId=self.client)

    def set_joints(self, q: np.ndarray) -> None:
        """Set the estimated joints to angles ``q`` (radians)."""
        for idx, value in zip(self._estimated, q):
            pb.resetJointState(self.id, idx, float(value), physicsClientId=self.client)

    def link_frame(self, link: str) -> np.ndarray:
        """World pose (4x4) of a URDF link frame, from PyBullet (not the inertial frame)."""
        idx = self.link_index[link]
        if idx == -1:
            pos, orn = pb.getBasePositionAndOrientation(self.id, physicsClientId=self.client)
            dyn = pb.getDynamicsInfo(self.id, -1, physicsClientId=self.client)
            T_world_com = pose_to_matrix(np.array(pos), np.array(orn))
            return T_world_com @ invert(pose_to_matrix(np.array(dyn[3]), np.array(dyn[4])))
        state = pb.getLinkState(self.id, idx, computeForwardKinematics=True, physicsClientId=self.client)
        return pose_to_matrix(np.array(state[4]), np.array(state[5]))

    def in_collision(self, others: list[int], margin: float = 0.003) -> bool:
        """True if movable links touch each other or any body in ``others`` deeper than ``margin`` m."""
        pb.performCollisionDetection(physicsClientId=self.client)
        for c in pb.getContactPoints(self.id, self.id, physicsClientId=self.client):
            if c[8] < -margin:
                return True
        for other in others:
            for c in pb.getClosestPoints(self.id, other, 0.0, physicsClientId=self.client):
                link = c[3]
                if link >= 0 and self.movable[link] and c[8] < -margin:
                    return True
        return False

    def remove(self) -> None:
        pb.removeBody(self.id, physicsClientId=self.client)
