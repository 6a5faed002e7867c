"""Simplified render meshes stay faithful to the URDF's full visual meshes."""
import numpy as np
import pybullet as pb
import pytest

from armpose.geometry import Camera, look_at
from armpose.robots import get_robot
from armpose.sim.body import RobotBody
from armpose.sim.camera import projection_matrix, view_matrix


def _silhouettes(spec, full: bool, poses, views, cam):
    client = pb.connect(pb.DIRECT)
    try:
        body = RobotBody(client, spec, full_meshes=full)
        out = []
        for q, V in zip(poses, views):
            body.set_joints(q)
            *_, seg = pb.getCameraImage(cam.width, cam.height, V, projection_matrix(cam),
                                        renderer=pb.ER_TINY_RENDERER, physicsClientId=client)
            out.append(np.asarray(seg).reshape(cam.height, cam.width) == body.id)
        return out
    finally:
        pb.disconnect(client)


@pytest.mark.parametrize("name", ["ur3", "ur5", "ur10", "iiwa", "panda"])
def test_simplified_meshes_match_full_meshes(name):
    spec = get_robot(name)
    cam = Camera(256, 212, 309.0, 309.0, 127.5, 105.5)  # the network input camera
    rng = np.random.default_rng(0)
    lim = np.array(spec.joint_limits)
    poses = rng.uniform(lim[:, 0], lim[:, 1], size=(6, spec.num_joints))
    views = [view_matrix(look_at([1.6 * np.cos(a), 1.6 * np.sin(a), 1.0], [0, 0, 0.4])) for a in np.linspace(0, 5, 6)]
    full = _silhouettes(spec, True, poses, views, cam)
    simple = _silhouettes(spec, False, poses, views, cam)
    ious = [(a & b).sum() / max(1, (a | b).sum()) for a, b in zip(full, simple)]
    assert min(ious) >= 0.97, ious
