"""Folder source of ``armpose import``: round trip, matching tolerance, every validation, atomic output."""
from __future__ import annotations

import json
import logging
from decimal import Decimal

import cv2
import numpy as np
import pytest

from armpose.geometry import Camera
from armpose.importers import SourceError, import_folder
from armpose.importers.cli import main
from armpose.recording import read_frame, read_joints, read_meta, read_poses
from armpose.robots.registry import get_robot

T0 = 1_700_000_000 * 10**9  # ns
IMAGE_DT, SAMPLE_DT = 100_000_000, 10_000_000  # 10 Hz images, 100 Hz joints and poses
CAMERA = Camera(32, 24, 30.0, 30.0, 15.5, 11.5)
JOINTS = get_robot("ur5").joints
QUAT = np.array([-0.5, 0.5, -0.5, 0.5])  # any unit quaternion with qw >= 0 (the written sign)


def stamp(ns: int, unit: str = "s") -> str:
    return str(Decimal(ns).scaleb(-{"s": 9, "ms": 6}[unit]))


def joint_values(k: int) -> np.ndarray:
    """Joint sample k, radians, in the robot's order."""
    return 0.1 * np.arange(len(JOINTS)) + 0.001 * k


def pose_values(k: int) -> np.ndarray:
    return np.concatenate([[1.0 + 0.001 * k, 0.2, 0.8], QUAT])


def make_folder(root, n=6, unit="s", listing=False, skip_joints=(), pose_glitch=(), columns=None):
    """A raw folder with ``n`` uniform images (value 10*i); joint samples at +2 ms, poses at -3 ms."""
    src = root / "raw"
    (src / "images").mkdir(parents=True)
    rows = []
    for i in range(n):
        t = T0 + i * IMAGE_DT
        name = f"img_{i}.png" if listing else f"{stamp(t, unit)}.png"
        cv2.imwrite(str(src / "images" / name), np.full((24, 32, 3), 10 * i, np.uint8))
        rows.append(f"{stamp(t, unit)},images/{name}")
    if listing:
        (src / "images.csv").write_text("timestamp,file\n" + "\n".join(rows) + "\n")
    columns = columns or ["timestamp", *reversed(JOINTS), "ee_fixed_joint"]
    lines = [",".join(columns)]
    poses = ["timestamp,x,y,z,qx,qy,qz,qw"]
    for k in range(-5, 10 * n + 5):
        if k not in skip_joints:
            q = dict(zip(JOINTS, joint_values(k)))
            lines.append(",".join([stamp(T0 + k * SAMPLE_DT + 2_000_000, unit)]
                                  + [repr(float(q.get(c, 0.0))) for c in columns[1:]]))
        p = pose_values(k) + (np.array([1.0, 0, 0, 0, 0, 0, 0]) if k in pose_glitch else 0)
        poses.append(",".join([stamp(T0 + k * SAMPLE_DT - 3_000_000, unit)] + [repr(float(v)) for v in p]))
    (src / "joint_states.csv").write_text("\n".join(lines) + "\n")
    (src / "camera_poses.csv").write_text("\n".join(poses) + "\n")
    return src


def run(src, out, **kw):
    return import_folder(src, out, "ur5", camera=CAMERA, tolerance_ms=kw.pop("tolerance_ms", 5.0), **kw)


def kept_images(out) -> list[int]:
    """Source image index of every written frame (from its uniform pixel value)."""
    meta, spec = read_meta(out)
    frames, _, _ = read_joints(out, spec)
    return [int(read_frame(out, int(f), meta.camera)[0, 0, 0]) // 10 for f in frames]


def test_folder_round_trip(tmp_path):
    src = make_folder(tmp_path)
    summary = run(src, tmp_path / "rec")
    assert summary["kept"] == 6 and summary["images"] == 6 and sum(summary["dropped"].values()) == 0
    assert summary["ignored"]["extra_joints"] == ["ee_fixed_joint"]
    meta, spec = read_meta(tmp_path / "rec")
    assert meta.source == "recorded" and meta.camera == CAMERA and meta.robot == "ur5"
    frames, joints, jerr = read_joints(tmp_path / "rec", spec)
    pframes, poses, perr = read_poses(tmp_path / "rec")
    assert not jerr and not perr and list(frames) == list(pframes) == list(range(6))
    np.testing.assert_allclose(joints, [joint_values(10 * i) for i in range(6)], atol=1e-12)
    np.testing.assert_allclose(poses, [pose_values(10 * i) for i in range(6)], atol=1e-9)
    assert kept_images(tmp_path / "rec") == list(range(6))
    assert summary["max_offset_ms"] == {"joints": 2.0, "pose": 3.0}


def test_images_csv_and_millisecond_stamps(tmp_path):
    src = make_folder(tmp_path, n=3, unit="ms", listing=True)
    summary = run(src, tmp_path / "rec", time_unit="ms")
    assert summary["kept"] == 3 and kept_images(tmp_path / "rec") == [0, 1, 2]


def test_tolerance_drops_and_counts_unmatched_frames(tmp_path):
    src = make_folder(tmp_path, skip_joints=range(15, 26))  # no joint sample within 50 ms of image 2
    summary = run(src, tmp_path / "rec")
    assert summary["kept"] == 5 and summary["dropped"]["no_joints_within_tolerance"] == 1
    assert kept_images(tmp_path / "rec") == [0, 1, 3, 4, 5]
    _, spec = read_meta(tmp_path / "rec")
    np.testing.assert_allclose(read_joints(tmp_path / "rec", spec)[1][2], joint_values(30))
    assert run(src, tmp_path / "wide", tolerance_ms=60.0)["kept"] == 6


def test_unknown_joint_name_aborts(tmp_path):
    src = make_folder(tmp_path, columns=["timestamp", *JOINTS[:2], "elbow_jiont", *JOINTS[3:]])
    with pytest.raises(SourceError) as err:
        run(src, tmp_path / "rec")
    assert err.value.file.endswith("joint_states.csv") and err.value.row == 1 and err.value.value == "elbow_jiont"
    assert "joint_states.csv:1:" in str(err.value) and "'elbow_jiont'" in str(err.value)
    assert not (tmp_path / "rec").exists()


def test_joint_timestamps_going_backwards_abort(tmp_path):
    src = make_folder(tmp_path)
    lines = (src / "joint_states.csv").read_text().splitlines()
    lines[4], lines[5] = lines[5], lines[4]
    (src / "joint_states.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(SourceError, match=r"joint_states\.csv:6: joint_states timestamp goes backwards") as err:
        run(src, tmp_path / "rec")
    assert err.value.value == lines[5].split(",")[0]


def test_image_not_named_by_timestamp_aborts(tmp_path):
    src = make_folder(tmp_path, n=2)
    cv2.imwrite(str(src / "images" / "frame_7.png"), np.zeros((24, 32, 3), np.uint8))
    with pytest.raises(SourceError, match=r"frame_7\.png: image name is not a timestamp in s; .*'frame_7\.png'"):
        run(src, tmp_path / "rec")


def test_image_listing_going_backwards_aborts(tmp_path):
    src = make_folder(tmp_path, n=3, listing=True)
    lines = (src / "images.csv").read_text().splitlines()
    lines[2], lines[3] = lines[3], lines[2]
    (src / "images.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(SourceError, match=r"images\.csv:4: image timestamp goes backwards"):
        run(src, tmp_path / "rec")


def test_non_numeric_joint_value_aborts(tmp_path):
    src = make_folder(tmp_path)
    text = (src / "joint_states.csv").read_text().splitlines()
    cells = text[7].split(",")
    cells[1] = "n/a"
    text[7] = ",".join(cells)
    (src / "joint_states.csv").write_text("\n".join(text) + "\n")
    with pytest.raises(SourceError, match=r"joint_states\.csv:8: wrist_3_joint is not a number \(value: 'n/a'\)"):
        run(src, tmp_path / "rec")


def test_inconsistent_image_size_aborts_and_leaves_nothing(tmp_path):
    src = make_folder(tmp_path)
    bad = sorted((src / "images").iterdir())[3]
    cv2.imwrite(str(bad), np.zeros((24, 40, 3), np.uint8))
    with pytest.raises(SourceError) as err:
        run(src, tmp_path / "out" / "rec")
    assert err.value.file == str(bad) and err.value.value == "40x24"
    assert "image size differs from the camera's 32x24" in str(err.value)
    assert list((tmp_path / "out").iterdir()) == []  # no recording, no half-built hidden folder


def test_pose_jump_drops_frames_around_it(tmp_path, caplog):
    src = make_folder(tmp_path, pose_glitch=range(28, 33))  # mocap glitch at image 3 only
    with caplog.at_level(logging.WARNING):
        summary = run(src, tmp_path / "rec", max_pose_jump_m=0.1)
    assert summary["dropped"]["pose_jump"] == 3 and summary["kept"] == 3
    assert kept_images(tmp_path / "rec") == [0, 1, 5]
    assert "camera_poses.csv:37" in caplog.text and "jumps 1.010 m" in caplog.text  # k=30: the glitch


def test_non_unit_quaternion_sample_is_dropped_and_counted(tmp_path):
    src = make_folder(tmp_path)
    lines = (src / "camera_poses.csv").read_text().splitlines()
    lines[26] = lines[26].rsplit(",", 1)[0] + ",0.0"  # k=20, image 2's partner
    (src / "camera_poses.csv").write_text("\n".join(lines) + "\n")
    summary = run(src, tmp_path / "rec")
    assert summary["ignored"]["invalid_pose_samples"] == 1
    assert summary["dropped"]["no_pose_within_tolerance"] == 1 and summary["kept"] == 5


def test_existing_output_is_kept_unless_overwrite(tmp_path):
    src = make_folder(tmp_path, n=2)
    (tmp_path / "rec").mkdir()
    with pytest.raises(FileExistsError):
        run(src, tmp_path / "rec")
    assert run(src, tmp_path / "rec", overwrite=True)["kept"] == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["raw", "rec"]


def test_cli_folder(tmp_path, capsys):
    src = make_folder(tmp_path, n=3)
    (tmp_path / "cam.json").write_text(json.dumps(CAMERA.to_dict()))
    argv = ["folder", str(src), str(tmp_path / "rec"), "--robot", "ur5", "--intrinsics", str(tmp_path / "cam.json"),
            "--tolerance-ms", "5"]
    assert main(argv) == 0
    assert "imported 3 of 3 images" in capsys.readouterr().out
    assert main(argv) == 1
    assert "exists" in capsys.readouterr().err
    assert main([*argv[:2], str(tmp_path / "none"), *argv[3:-1], "0"]) == 1  # tolerance 0 ms: nothing kept
    out, err = capsys.readouterr()
    assert "imported 0 of 3 images" in out and "3 no_joints_within_tolerance" in out and "no frame kept" in err
    assert not (tmp_path / "none").exists()
    (src / "camera_poses.csv").unlink()
    assert main([*argv[:2], str(tmp_path / "b"), *argv[3:], "--camera-pose", "1,0,0.5,0,0,0,1"]) == 0
    assert read_poses(tmp_path / "b")[1][0].tolist() == [1, 0, 0.5, 0, 0, 0, 1]
    assert main([*argv[:2], str(tmp_path / "c"), *argv[3:]]) == 1
    assert "camera_poses.csv: missing file" in capsys.readouterr().err
