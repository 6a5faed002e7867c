"""Robot masks by rendering the robot model alone at the recorded camera pose (TinyRenderer)."""
from __future__ import annotations

import numpy as np
import pybullet as pb

from armpose.geometry import Camera
from armpose.robots.registry import RobotSpec
from armpose.sim.body import RobotBody
from armpose.sim.camera import projection_matrix, view_matrix


class MaskRenderer:
    """Renders boolean robot masks for one robot type in a private PyBullet client."""

    def __init__(self, spec: RobotSpec):
        self.spec = spec
        self.client = pb.connect(pb.DIRECT)
        self.body = RobotBody(self.client, spec)

    def render(self, q: np.ndarray, T_base_cam: np.ndarray, camera: Camera) -> np.ndarray:
        """Mask ``(H, W)`` bool of the robot at joint angles ``q`` (radians) seen by ``camera``
        whose optical frame has pose ``T_base_cam`` in the robot base frame."""
        self.body.set_joints(q)
        _, _, _, _, seg = pb.getCameraImage(
            camera.width, camera.height, view_matrix(T_base_cam), projection_matrix(camera),
            renderer=pb.ER_TINY_RENDERER, physicsClientId=self.client)
        return np.asarray(seg).reshape(camera.height, camera.width) == self.body.id

    def close(self) -> None:
        pb.disconnect(self.client)


_RENDERERS: dict[str, MaskRenderer] = {}


def mask_renderer(spec: RobotSpec) -> MaskRenderer:
    """A per-process cached :class:`MaskRenderer` (loading a URDF costs up to a second)."""
    if spec.name not in _RENDERERS:
        _RENDERERS[spec.name] = MaskRenderer(spec)
    return _RENDERERS[spec.name]
