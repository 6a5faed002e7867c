"""Helpers of ``armpose import``: timestamps, nearest matching, transforms and their composition."""
from __future__ import annotations

import json

import numpy as np
import pytest

from armpose.geometry import pose_to_matrix
from armpose.importers.common import (Where, base_from_world, compose_poses, load_transform, match_nearest,
                                      parse_stamp)


def test_parse_stamp_is_exact_nanoseconds():
    where = Where("x.csv", 3)
    assert parse_stamp("1700000000.123456789", "s", where) == 1_700_000_000_123_456_789
    assert parse_stamp("1.5", "ms", where) == 1_500_000
    with pytest.raises(ValueError, match=r"x\.csv:3: timestamp is not a number .*'12:00'"):
        parse_stamp("12:00", "s", where)


def test_match_nearest_within_tolerance_ties_to_earlier():
    stamps = np.array([0, 10, 20])
    assert match_nearest(np.array([-5, 4, 5, 6, 26, 31]), stamps, 5).tolist() == [0, 0, 0, 1, -1, -1]
    assert match_nearest(np.array([3]), np.zeros(0, np.int64), 5).tolist() == [-1]


def test_load_transform_forms(tmp_path):
    pose = [0.1, 0.2, 0.3, 0.0, 0.0, 0.70710678, 0.70710678]
    expected = pose_to_matrix(pose[:3], np.array(pose[3:]) / np.linalg.norm(pose[3:]))
    keys = dict(zip(["x", "y", "z", "qx", "qy", "qz", "qw"], pose))
    calibrate_rig_output = {"T_rig_cam": expected.tolist(), "translation": pose[:3], "views_used": 12}
    for i, content in enumerate([keys, {"T_rig_cam": keys}, {"matrix": expected.tolist()}, calibrate_rig_output,
                                 {"translation": pose[:3], "quaternion_xyzw": pose[3:]}]):
        (tmp_path / f"t{i}.json").write_text(json.dumps(content))
        np.testing.assert_allclose(load_transform(tmp_path / f"t{i}.json", "T", "T_rig_cam"), expected, atol=1e-8)
    np.testing.assert_allclose(load_transform(",".join(map(str, pose)), "T"), expected, atol=1e-12)
    with pytest.raises(ValueError, match="quaternion is not unit"):
        load_transform("0,0,0,0,0,0,2", "--camera-pose")
    (tmp_path / "bad.json").write_text(json.dumps({"x": 1}))
    with pytest.raises(ValueError, match=r"bad\.json: T_rig_cam needs a 4x4 matrix"):
        load_transform(tmp_path / "bad.json", "T_rig_cam")
    (tmp_path / "mirror.json").write_text(json.dumps({"matrix": np.diag([1.0, 1.0, -1.0, 1.0]).tolist()}))
    with pytest.raises(ValueError, match="not a 4x4 rigid transform"):
        load_transform(tmp_path / "mirror.json", "T_rig_cam")


def test_compose_mocap_pose_into_base_frame():
    T_world_base = pose_to_matrix([2.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0])  # base turned 180 deg about z
    T_rig_cam = pose_to_matrix([0.0, 0.0, 0.1], [0.0, 0.0, 0.0, 1.0])
    rig = np.array([[1.0, 0.0, 0.5, 0.0, 0.0, 0.0, 1.0]])  # rig 1 m in front of the base, in the world
    out = compose_poses(rig, base_from_world(T_world_base), T_rig_cam)
    np.testing.assert_allclose(out[0, :3], [1.0, 0.0, 0.6], atol=1e-12)
    np.testing.assert_allclose(np.abs(out[0, 3:]), [0, 0, 1, 0], atol=1e-12)


def test_load_transform_names_a_missing_or_broken_file(tmp_path):
    with pytest.raises(ValueError, match=r"nope\.json: missing file"):
        load_transform(tmp_path / "nope.json", "--rig-offset")
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(ValueError, match=r"bad\.json:1: not valid JSON"):
        load_transform(tmp_path / "bad.json", "--rig-offset")
