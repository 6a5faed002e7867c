"""Bag source of ``armpose import``: small real ROS 1 and ROS 2 bags written with rosbags' writers."""
from __future__ import annotations

import json
import logging

import cv2
import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from armpose.geometry import Camera, pose_to_matrix
from armpose.importers import SourceError, import_bag
from armpose.importers.cli import main
from armpose.recording import read_frame, read_joints, read_meta, read_poses
from armpose.robots.registry import get_robot

T0 = 1_700_000_000 * 10**9  # ns
CAMERA = Camera(32, 24, 30.0, 30.0, 15.5, 11.5)
JOINTS = get_robot("ur5").joints
QUAT = np.array([-0.5, 0.5, -0.5, 0.5])
T_RIG_CAM = {"x": 0.05, "y": -0.02, "z": 0.1, "qx": 0.0, "qy": 0.0, "qz": 0.38268343, "qw": 0.92387953}
IMAGE, JOINT, POSE, INFO = "/camera/color/image_raw", "/joint_states", "/mocap/rig/pose", "/camera/color/camera_info"
STORES = {1: Stores.ROS1_NOETIC, 2: Stores.ROS2_HUMBLE}


@pytest.fixture(scope="module")
def stores():
    return {ros: get_typestore(store) for ros, store in STORES.items()}


def header(ts, ros, ns):
    stamp = ts.types["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
    Header = ts.types["std_msgs/msg/Header"]
    return Header(seq=0, stamp=stamp, frame_id="f") if ros == 1 else Header(stamp=stamp, frame_id="f")


def rgb_of(i, size=(24, 32)):
    """Image i: uniform colour (10 i, 100, 200)."""
    return np.broadcast_to(np.array([10 * i, 100, 200], np.uint8), (*size, 3)).copy()


def image_msg(ts, ros, ns, rgb, kind):
    h, w = rgb.shape[:2]
    if kind == "png":
        data = np.frombuffer(cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))[1].tobytes(), np.uint8)
        return "sensor_msgs/msg/CompressedImage", ts.types["sensor_msgs/msg/CompressedImage"](
            header=header(ts, ros, ns), format="png", data=data)
    pixels = rgb if kind == "rgb8" else rgb[..., ::-1]
    return "sensor_msgs/msg/Image", ts.types["sensor_msgs/msg/Image"](
        header=header(ts, ros, ns), height=h, width=w, encoding=kind, is_bigendian=0, step=w * 3,
        data=np.ascontiguousarray(pixels).reshape(-1))


def joint_msg(ts, ros, ns, names, positions):
    return "sensor_msgs/msg/JointState", ts.types["sensor_msgs/msg/JointState"](
        header=header(ts, ros, ns), name=list(names), position=np.asarray(positions, np.float64),
        velocity=np.zeros(0), effort=np.zeros(0))


def pose_msg(ts, ros, ns, pose):
    g = ts.types
    return "geometry_msgs/msg/PoseStamped", g["geometry_msgs/msg/PoseStamped"](
        header=header(ts, ros, ns), pose=g["geometry_msgs/msg/Pose"](
            position=g["geometry_msgs/msg/Point"](x=pose[0], y=pose[1], z=pose[2]),
            orientation=g["geometry_msgs/msg/Quaternion"](x=pose[3], y=pose[4], z=pose[5], w=pose[6])))


def info_msg(ts, ros, ns, cam):
    K = np.array([cam.fx - 1, 0, cam.cx, 0, cam.fy - 1, cam.cy, 0, 0, 1])  # P wins: K differs on purpose
    P = np.array([cam.fx, 0, cam.cx, 0, 0, cam.fy, cam.cy, 0, 0, 0, 1, 0])
    roi = ts.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    mats = dict(zip("DKRP", (np.zeros(5), K, np.eye(3).reshape(-1), P)))
    mats = mats if ros == 1 else {k.lower(): v for k, v in mats.items()}
    return "sensor_msgs/msg/CameraInfo", ts.types["sensor_msgs/msg/CameraInfo"](
        header=header(ts, ros, ns), height=cam.height, width=cam.width, distortion_model="plumb_bob",
        binning_x=0, binning_y=0, roi=roi, **mats)


def joint_values(k):
    return 0.1 * np.arange(len(JOINTS)) + 0.001 * k


def pose_values(k):
    return np.concatenate([[1.0 + 0.001 * k, 0.2, 0.8], QUAT])


def write_bag(tmp_path, stores, ros=1, n=5, kind="rgb8", info=True, mocap=True, gripper=False, skip_joints=(),
              bad_name_at=None, pose_glitch=(), stamp_shift=None, size_at=None):
    """A bag with n images at 10 Hz and joints / mocap poses at 100 Hz (at +2 ms / -3 ms).

    Every message is recorded 1 ms after its header stamp; ``stamp_shift = (i, ns)`` moves image
    i's header stamp only.
    """
    ts = stores[ros]
    msgs = []  # (topic, record ns, (msgtype, msg))
    for i in range(n):
        t = T0 + i * 100_000_000
        shifted = t + (stamp_shift[1] if stamp_shift and stamp_shift[0] == i else 0)
        rgb = rgb_of(i, (24, 40) if i == size_at else (24, 32))
        msgs.append((IMAGE, t + 1_000_000, image_msg(ts, ros, shifted, rgb, kind)))
    if info:
        msgs.append((INFO, T0, info_msg(ts, ros, T0 - 1_000_000, CAMERA)))
    for k in range(-5, 10 * n + 5):
        t = T0 + k * 10_000_000
        names = [*reversed(JOINTS), "ee_fixed_joint"]
        if k == bad_name_at:
            names[3] = "elbow_jiont"
        values = dict(zip(JOINTS, joint_values(k)))
        if k not in skip_joints:
            msgs.append((JOINT, t + 3_000_000, joint_msg(ts, ros, t + 2_000_000, names,
                                                         [values.get(j, 0.0) for j in names])))
        if gripper and k % 5 == 0:
            msgs.append((JOINT, t + 4_000_000, joint_msg(ts, ros, t + 3_000_000, ["gripper_joint"], [0.01])))
        if mocap:
            pose = pose_values(k) + (np.array([1.0, 0, 0, 0, 0, 0, 0]) if k in pose_glitch else 0)
            msgs.append((POSE, t - 2_000_000, pose_msg(ts, ros, t - 3_000_000, pose)))
    path = tmp_path / ("in.bag" if ros == 1 else "in_bag2")
    writer = Writer1(path) if ros == 1 else Writer2(path, version=Writer2.VERSION_LATEST)
    with writer:
        conns = {}
        for topic, t, (msgtype, msg) in sorted(msgs, key=lambda m: m[1]):
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=ts)
            raw = ts.serialize_ros1(msg, msgtype) if ros == 1 else ts.serialize_cdr(msg, msgtype)
            writer.write(conns[topic], t, raw)
    return path


def kept_images(out):
    """Source image index of each written frame, checking the colour channels on the way."""
    meta, spec = read_meta(out)
    frames, _, errors = read_joints(out, spec)
    assert not errors
    pixels = [read_frame(out, int(f), meta.camera)[0, 0] for f in frames]
    assert all(list(p[1:]) == [100, 200] for p in pixels)
    return [int(p[0]) // 10 for p in pixels]


def test_ros1_bag_with_mocap_rig_and_camera_info(tmp_path, stores):
    bag = write_bag(tmp_path, stores, ros=1, gripper=True)
    T_rig_cam = pose_to_matrix([T_RIG_CAM[k] for k in "xyz"], [T_RIG_CAM[k] for k in ("qx", "qy", "qz", "qw")])
    summary = import_bag(bag, tmp_path / "rec", "ur5", pose_topic=POSE, T_rig_cam=T_rig_cam, tolerance_ms=5)
    assert summary["kept"] == 5 and summary["ignored"]["extra_joints"] == ["ee_fixed_joint"]
    assert summary["ignored"]["joint_messages_without_robot_joints"] == len(range(-5, 55, 5))
    meta, spec = read_meta(tmp_path / "rec")
    assert meta.camera == CAMERA and meta.source == "recorded"
    _, joints, _ = read_joints(tmp_path / "rec", spec)
    np.testing.assert_allclose(joints, [joint_values(10 * i) for i in range(5)], atol=1e-12)
    _, poses, errors = read_poses(tmp_path / "rec")
    assert not errors
    for i, pose in enumerate(poses):
        expected = pose_to_matrix(pose_values(10 * i)[:3], QUAT) @ T_rig_cam
        np.testing.assert_allclose(pose_to_matrix(pose[:3], pose[3:]), expected, atol=1e-7)
    assert kept_images(tmp_path / "rec") == list(range(5))


def test_ros2_bag_bgr8_fixed_camera(tmp_path, stores):
    bag = write_bag(tmp_path, stores, ros=2, kind="bgr8", info=False, mocap=False)
    fixed = np.array([1.5, 0.0, 0.6, -0.5, 0.5, -0.5, 0.5])
    summary = import_bag(bag, tmp_path / "rec", "ur5", camera=CAMERA, camera_pose=fixed, tolerance_ms=5)
    assert summary["kept"] == 5 and summary["camera_pose_from"] == "fixed camera pose"
    np.testing.assert_allclose(read_poses(tmp_path / "rec")[1], np.tile(fixed, (5, 1)))
    assert kept_images(tmp_path / "rec") == list(range(5))


def test_ros2_bag_compressed_images(tmp_path, stores):
    bag = write_bag(tmp_path, stores, ros=2, kind="png", n=3)
    summary = import_bag(bag / "metadata.yaml", tmp_path / "rec", "ur5", pose_topic=POSE, tolerance_ms=5)
    assert summary["kept"] == 3 and summary["intrinsics_from"] == f"CameraInfo topic {INFO}"
    assert kept_images(tmp_path / "rec") == [0, 1, 2]


def test_bag_tolerance_drops_and_counts_unmatched_frames(tmp_path, stores):
    bag = write_bag(tmp_path, stores, ros=2, skip_joints=range(16, 25))  # nearest to image 2: 48 ms away
    summary = import_bag(bag, tmp_path / "rec", "ur5", pose_topic=POSE, tolerance_ms=5)
    assert summary["dropped"] == {"no_joints_within_tolerance": 1, "no_pose_within_tolerance": 0, "pose_jump": 0}
    assert kept_images(tmp_path / "rec") == [0, 1, 3, 4]
    assert import_bag(bag, tmp_path / "wide", "ur5", pose_topic=POSE, tolerance_ms=50)["kept"] == 5


def test_bag_unknown_joint_name_aborts(tmp_path, stores):
    bag = write_bag(tmp_path, stores, ros=1, bad_name_at=2)  # joint message index 7
    with pytest.raises(SourceError) as err:
        import_bag(bag, tmp_path / "rec", "ur5", pose_topic=POSE)
    assert err.value.where.topic == JOINT and err.value.where.index == 7 and err.value.value == "elbow_jiont"
    assert f"{bag} [topic /joint_states, message 7, stamp 1700000000.022000000 s]" in str(err.value)
    assert "not in robot 'ur5''s URDF" in str(err.value)
    assert not (tmp_path / "rec").exists()


def test_bag_image_stamps_going_backwards_abort(tmp_path, stores):
    bag = write_bag(tmp_path, stores, ros=2, stamp_shift=(2, -150_000_000))
    with pytest.raises(SourceError, match=rf"\[topic {IMAGE}, message 2, stamp 1700000000.050000000 s\]: "
                                          r"image timestamp goes backwards"):
        import_bag(bag, tmp_path / "rec", "ur5", pose_topic=POSE)
    summary = import_bag(bag, tmp_path / "rec", "ur5", pose_topic=POSE, stamp="bag", tolerance_ms=5)
    assert summary["kept"] == 5  # the record times are in order


def test_bag_inconsistent_image_size_aborts(tmp_path, stores):
    bag = write_bag(tmp_path, stores, ros=1, size_at=3)
    with pytest.raises(SourceError) as err:
        import_bag(bag, tmp_path / "out" / "rec", "ur5", pose_topic=POSE, tolerance_ms=5)
    assert err.value.value == "40x24" and err.value.where.index == 3
    assert f"[topic {IMAGE}, message 3," in str(err.value) and "camera's 32x24" in str(err.value)
    assert list((tmp_path / "out").iterdir()) == []


def test_bag_pose_jump_drops_frames(tmp_path, stores, caplog):
    bag = write_bag(tmp_path, stores, ros=2, pose_glitch=range(29, 32))
    with caplog.at_level(logging.WARNING):
        summary = import_bag(bag, tmp_path / "rec", "ur5", pose_topic=POSE, tolerance_ms=5, max_pose_jump_m=0.2)
    assert summary["dropped"]["pose_jump"] == 3 and kept_images(tmp_path / "rec") == [0, 1]
    assert f"[topic {POSE}, message 35, stamp 1700000000.297000000 s]" in caplog.text


def test_bag_wrong_topic_type_and_missing_intrinsics(tmp_path, stores):
    bag = write_bag(tmp_path, stores, ros=2, info=False, n=2)
    with pytest.raises(SourceError, match=r"topic /joint_states\]: camera pose topic must be of type"):
        import_bag(bag, tmp_path / "rec", "ur5", pose_topic=JOINT)
    with pytest.raises(ValueError, match="no camera intrinsics"):
        import_bag(bag, tmp_path / "rec", "ur5", pose_topic=POSE)


def test_cli_bag(tmp_path, stores, capsys):
    bag = write_bag(tmp_path, stores, ros=1, n=3)
    T = pose_to_matrix([T_RIG_CAM[k] for k in "xyz"], [T_RIG_CAM[k] for k in ("qx", "qy", "qz", "qw")])
    (tmp_path / "T_rig_cam.json").write_text(json.dumps({"T_rig_cam": T.tolist(), "views_used": 9}))  # calibrate-rig
    argv = ["bag", str(bag), str(tmp_path / "rec"), "--robot", "ur5", "--pose-topic", POSE,
            "--T-rig-cam", str(tmp_path / "T_rig_cam.json"), "--tolerance-ms", "5", "--json"]
    assert main(argv) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["kept"] == 3 and summary["camera"] == CAMERA.to_dict()
    pose = read_poses(tmp_path / "rec")[1][0]
    expected = pose_to_matrix(pose_values(0)[:3], QUAT) @ T
    np.testing.assert_allclose(pose_to_matrix(pose[:3], pose[3:]), expected, atol=1e-7)
    assert main([*argv[:2], str(tmp_path / "b"), *argv[3:], "--camera-pose", "1,0,0,0,0,0,1"]) == 1
    assert "T_rig_cam and T_world_base apply to pose streams only" in capsys.readouterr().err
