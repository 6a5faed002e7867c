"""Batched pytorch-kinematics FK (float64) against PyBullet's link frames, for every robot."""
import numpy as np
import pybullet as pb
import pytest

from armpose.robots import all_robots, get_robot
from armpose.robots.kinematics import Kinematics
from armpose.sim.body import RobotBody

BUILTIN = ["ur3", "ur5", "ur10", "iiwa", "panda"]


@pytest.mark.parametrize("name", BUILTIN)
def test_fk_matches_pybullet_link_frames(name):
    spec = get_robot(name)
    kin = Kinematics(spec)
    client = pb.connect(pb.DIRECT)
    try:
        T_world_base = np.eye(4)
        T_world_base[:3, 3] = [0.3, -0.2, 0.1]
        body = RobotBody(client, spec, kin, T_world_base=T_world_base)
        np.testing.assert_allclose(body.link_frame(spec.base_link), T_world_base, atol=1e-6)
        rng = np.random.default_rng(1)
        lim = np.array(spec.joint_limits)
        q = rng.uniform(lim[:, 0], lim[:, 1], size=(16, spec.num_joints))
        fk = kin.joint_positions(q)  # (16, J, 3), base frame, one batched call
        assert fk.dtype == np.float64 and fk.shape == (16, spec.num_joints, 3)
        for qi, fki in zip(q, fk):
            body.set_joints(qi)
            ref = np.array([(np.linalg.inv(T_world_base) @ body.link_frame(link))[:3, 3] for link in kin.child_links])
            np.testing.assert_allclose(fki, ref, atol=1e-6)
    finally:
        pb.disconnect(client)


def test_registry_has_the_five_robot_types():
    robots = all_robots()
    assert {"ur3", "ur5", "ur10", "iiwa", "panda"} <= set(robots)
    families = {n: robots[n].family for n in BUILTIN}
    assert families == {"ur3": "UR", "ur5": "UR", "ur10": "UR", "iiwa": "KUKA", "panda": "Panda"}
    assert [robots[n].num_joints for n in BUILTIN] == [6, 6, 6, 7, 7]


@pytest.mark.parametrize("name", BUILTIN)
def test_joint_limits_lie_within_the_urdf(name):
    spec = get_robot(name)
    client = pb.connect(pb.DIRECT)
    try:
        body = RobotBody(client, spec)
        for joint, (lo, hi) in zip(spec.joints, spec.joint_limits):
            info = pb.getJointInfo(body.id, body.joint_index[joint], physicsClientId=client)
            assert info[8] - 1e-3 <= lo < hi <= info[9] + 1e-3, (joint, lo, hi, info[8], info[9])
    finally:
        pb.disconnect(client)


@pytest.mark.parametrize("name", BUILTIN)
def test_serial_chain_matches_pytorch_kinematics(name):
    """The kinematic fit's compiled chain gives the same joint positions as pytorch-kinematics
    (float64), with the base at the origin, batched and unbatched."""
    import torch
    from armpose.robots.kinematics import SerialChain
    kin = Kinematics(get_robot(name))
    chain = SerialChain(kin)
    lim = np.array(kin.spec.joint_limits)
    q = np.random.default_rng(7).uniform(lim[:, 0], lim[:, 1], (40, len(lim)))
    got = chain.positions(torch.tensor(q)).numpy()
    np.testing.assert_allclose(got[:, 1:], kin.joint_positions(q), atol=1e-12)
    assert np.abs(got[:, 0]).max() == 0.0
    np.testing.assert_allclose(chain.positions(torch.tensor(q[0])).numpy(), got[0], atol=1e-12)


def test_axis_angle_matrix_is_a_rotation_and_smooth_at_zero():
    import torch
    from armpose.robots.kinematics import axis_angle_matrix
    v = torch.tensor([[0.0, 0.0, 0.0], [1e-6, -2e-6, 0.0], [0.3, -1.2, 2.0], [0.0, 0.0, np.pi / 2]], dtype=torch.float64)
    R = axis_angle_matrix(v)
    np.testing.assert_allclose((R @ R.transpose(1, 2)).numpy(), np.tile(np.eye(3), (4, 1, 1)), atol=1e-12)
    np.testing.assert_allclose(R[3].numpy(), [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)
    axis = v[2] / v[2].norm()
    np.testing.assert_allclose((R[2] @ axis).numpy(), axis.numpy(), atol=1e-12)   # the axis is fixed
