"""Label geometry is exact against independent sources, for all five robots.

The labels stage sees only the recording (frames, joints.csv, camera_poses.csv). Here the
recording is made by hand from a PyBullet scene whose state we keep, so the labels can be
checked against that scene: the mask against PyBullet's segmentation buffer of the full
scene (robot pixels, camera set to the network input's intrinsics), the joint positions
against PyBullet's link frames.
"""
import copy

import numpy as np
import pybullet as pb
import pytest

from armpose.config import profile_params
from armpose.geometry import Camera, invert, matrix_to_quat
from armpose.labels.compute import label_recording
from armpose.recording import RecordingMeta, write_frame, write_tables
from armpose.robots import get_robot
from armpose.robots.kinematics import Kinematics
from armpose.sim.body import RobotBody
from armpose.sim.camera import projection_matrix, view_matrix
from armpose.sim.sampling import collision_free_configuration, sample_camera_pose
from armpose.sim.scene import SceneRandomizer

FRAMES = 4


def _scene_recording(name: str, rec_dir, seed: int):
    """Render FRAMES unoccluded frames of robot ``name``; return the recording and the truth."""
    params = profile_params("default")
    cfg = copy.deepcopy(params["render"])
    cfg["randomize"]["background"].update(distractors=[0, 0], other_robot_prob=0.0)
    cfg["camera"]["elevation_deg"] = [15.0, 60.0]  # above the table top: the table cannot hide the robot
    cam = Camera.from_dict(params["base"]["camera"])
    size = params["base"]["input_size"]
    crop = cam.scale_crop(size["width"], size["height"])[0]
    spec = get_robot(name)
    kin = Kinematics(spec)
    rng = np.random.default_rng(seed)
    client = pb.connect(pb.DIRECT)
    truth = {"masks": [], "joints": [], "base": []}
    qs, poses = np.zeros((FRAMES, spec.num_joints)), np.zeros((FRAMES, 7))
    try:
        body = RobotBody(client, spec, kin, self_collision=True)
        scene = SceneRandomizer(client, rng, cfg["randomize"], spec.reach, max(cfg["camera"]["distance"]))
        for k in range(FRAMES):
            support = scene.new_scene()
            q = collision_free_configuration(body, support, rng)
            pts = np.vstack([np.zeros((1, 3)), kin.joint_positions(q[None])[0]])
            T = sample_camera_pose(pts, cam, cfg["camera"], rng)
            light = scene.lighting()
            _, _, rgba, _, _ = pb.getCameraImage(cam.width, cam.height, view_matrix(T), projection_matrix(cam),
                                                 renderer=pb.ER_TINY_RENDERER, physicsClientId=client, **light)
            write_frame(rec_dir, k, np.asarray(rgba, np.uint8).reshape(cam.height, cam.width, 4)[..., :3])
            *_, seg = pb.getCameraImage(crop.width, crop.height, view_matrix(T), projection_matrix(crop),
                                        renderer=pb.ER_TINY_RENDERER, physicsClientId=client, **light)
            truth["masks"].append(np.asarray(seg).reshape(crop.height, crop.width) == body.id)
            T_cam_world = invert(T)  # world = robot base frame
            truth["joints"].append([(T_cam_world @ body.link_frame(link))[:3, 3] for link in kin.child_links])
            truth["base"].append((T_cam_world @ body.link_frame(spec.base_link))[:3, 3])
            qs[k], poses[k, :3], poses[k, 3:] = q, T[:3, 3], matrix_to_quat(T[:3, :3])
    finally:
        pb.disconnect(client)
    write_tables(rec_dir, RecordingMeta(name, cam, "synthetic"), spec, np.arange(FRAMES), qs, poses)
    return params, {k: np.array(v) for k, v in truth.items()}


@pytest.mark.parametrize("name", ["ur3", "ur5", "ur10", "iiwa", "panda"])
def test_labels_match_pybullet_scene(name, tmp_path):
    params, truth = _scene_recording(name, tmp_path / name, seed=7)
    arrays, _, skipped = label_recording(tmp_path / name, params["base"]["input_size"], params["base"]["max_joints"])
    assert not skipped and arrays["masks"].shape[0] == FRAMES
    J = get_robot(name).num_joints
    for k in range(FRAMES):
        label, ref = arrays["masks"][k].astype(bool), truth["masks"][k]
        assert ref.sum() > 50, "robot not in view"
        iou = (label & ref).sum() / (label | ref).sum()
        assert iou >= 0.99, f"frame {k}: mask IoU {iou:.4f}"
    np.testing.assert_allclose(arrays["joints"][:, :J], truth["joints"], atol=1e-3)
    np.testing.assert_allclose(arrays["base"], truth["base"], atol=1e-3)
    assert not arrays["joint_valid"][:, J:].any() and arrays["joint_valid"][:, :J].all()
    np.testing.assert_allclose(arrays["distance"], np.linalg.norm(truth["base"], axis=1), atol=1e-3)
