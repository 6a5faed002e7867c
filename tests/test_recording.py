"""Bad-input rules of the ``labels`` stage.

Every bad input stops labelling with a :class:`RecordingError` whose message names the
file, the row (where the problem is in a row) and the offending value. With
``skip_bad=True`` (``armpose labels --skip-bad``) a bad frame is instead skipped, logged
and counted. A failed stage run never leaves a ``data/labels/index.json`` that looks
complete, and never spoils a previous complete dataset.
"""
from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest

import armpose.labels.dataset as dataset_mod
from armpose.config import profile_params
from armpose.geometry import Camera, look_at, matrix_to_quat
from armpose.labels.compute import label_recording
from armpose.labels.dataset import ARRAYS, load_dataset
from armpose.recording import (RecordingError, RecordingMeta, frame_path, read_poses, write_frame,
                               write_tables)
from armpose.robots.registry import get_robot
from armpose.stages import labels as labels_stage

ROBOT = "iiwa"
CAMERA = Camera(480, 360, 525.0, 525.0, 239.5, 179.5)
INPUT_SIZE = {"width": 64, "height": 48}  # small network input: labelling stays fast
MAX_JOINTS = 7
NUM_FRAMES = 3


# --------------------------------------------------------------------------- fixtures

def random_image(seed: int, camera: Camera = CAMERA) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (camera.height, camera.width, 3), dtype=np.uint8)


def make_recording(rec_dir: Path, n: int = NUM_FRAMES, robot: str = ROBOT) -> Path:
    """A valid recording of ``n`` frames: random images, a fixed camera pose, small joint angles."""
    spec = get_robot(robot)
    frames = np.arange(n)
    joints = np.linspace(-0.3, 0.3, n)[:, None] * np.ones((1, spec.num_joints))
    T = look_at(eye=[2.0, 0.5, 1.0], target=[0.0, 0.0, 0.5])
    pose = np.concatenate([T[:3, 3], matrix_to_quat(T[:3, :3])])
    poses = np.tile(pose, (n, 1))
    for f in frames:
        write_frame(rec_dir, int(f), random_image(int(f)))
    write_tables(rec_dir, RecordingMeta(robot, CAMERA, "recorded", "test fixture"), spec, frames, joints, poses)
    return rec_dir


def set_cell(path: Path, line: int, column: str, value: str) -> None:
    """Replace one cell of a CSV, addressed by line number (header = 1) and column name."""
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    cells = lines[line - 1].split(",")
    cells[header.index(column)] = value
    lines[line - 1] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")


def label(rec_dir: Path, skip_bad: bool = False):
    return label_recording(rec_dir, INPUT_SIZE, MAX_JOINTS, skip_bad=skip_bad)


def assert_names(err: RecordingError, file: Path, row: int | None, value_text: str) -> str:
    """The message names the file, the row (``file:row``) and the offending value."""
    msg = str(err)
    assert err.file == str(file)
    assert str(file) in msg
    assert err.row == row
    if row is not None:
        assert f"{file}:{row}:" in msg
    assert f"(value: {value_text})" in msg
    return msg


@pytest.fixture
def rec(tmp_path) -> Path:
    return make_recording(tmp_path / "rec")


# --------------------------------------------------------------------------- a good recording

def test_valid_recording_labels_every_frame(rec):
    arrays, meta, skipped = label(rec)
    assert skipped == []
    assert meta.robot == ROBOT and meta.camera == CAMERA
    assert arrays["frame"].tolist() == list(range(NUM_FRAMES))
    assert arrays["images"].shape == (NUM_FRAMES, 48, 64, 3)
    assert arrays["masks"].shape == (NUM_FRAMES, 48, 64)
    assert arrays["masks"].any(), "the robot should be in view of the fixture camera"
    assert np.isfinite(arrays["joints"]).all() and arrays["joint_valid"].all()
    assert np.allclose(arrays["distance"], np.linalg.norm([2.0, 0.5, 1.0]), atol=1e-5)


# --------------------------------------------------------------------------- one bad input each

def test_missing_frame_png(rec):
    missing = frame_path(rec, 1)
    missing.unlink()
    with pytest.raises(RecordingError) as info:
        label(rec)
    msg = assert_names(info.value, missing, None, "1")
    assert "000001.png" in msg and "missing" in msg


def test_corrupt_frame_png(rec):
    bad = frame_path(rec, 2)
    garbage = np.random.default_rng(7).integers(0, 256, 1234, dtype=np.uint8).tobytes()
    bad.write_bytes(garbage)
    with pytest.raises(RecordingError) as info:
        label(rec)
    msg = assert_names(info.value, bad, None, "1234")  # the value is the file's size in bytes
    assert "000002.png" in msg and "corrupt" in msg


def test_frame_of_wrong_image_size(rec):
    bad = frame_path(rec, 0)
    write_frame(rec, 0, random_image(0, Camera(320, 240, 1, 1, 0, 0)))
    with pytest.raises(RecordingError) as info:
        label(rec)
    msg = assert_names(info.value, bad, None, "'320x240'")
    assert "480x360" in msg  # the size it should have been


@pytest.mark.parametrize("cell, value_text", [("nan", "'nan'"), ("", "''"), ("inf", "'inf'"), ("abc", "'abc'")],
                         ids=["nan", "empty", "inf", "not-a-number"])
def test_nan_or_missing_joint_reading(rec, cell, value_text):
    joints_csv = rec / "joints.csv"
    set_cell(joints_csv, 3, "lbr_iiwa_joint_4", cell)  # line 3 = frame 1
    with pytest.raises(RecordingError) as info:
        label(rec)
    msg = assert_names(info.value, joints_csv, 3, value_text)
    assert "lbr_iiwa_joint_4" in msg  # names the column too


def test_joints_header_count_mismatch(rec):
    joints_csv = rec / "joints.csv"
    lines = [",".join(line.split(",")[:-1]) for line in joints_csv.read_text().splitlines()]
    joints_csv.write_text("\n".join(lines) + "\n")  # the last joint's column is gone
    with pytest.raises(RecordingError) as info:
        label(rec)
    header = ["frame"] + [f"lbr_iiwa_joint_{i}" for i in range(1, 7)]
    msg = assert_names(info.value, joints_csv, 1, repr(header))
    assert "missing ['lbr_iiwa_joint_7']" in msg


def test_joints_header_name_mismatch(rec):
    joints_csv = rec / "joints.csv"
    text = joints_csv.read_text()
    joints_csv.write_text(text.replace("lbr_iiwa_joint_3", "shoulder_lift", 1))
    with pytest.raises(RecordingError) as info:
        label(rec)
    err = info.value
    msg = assert_names(err, joints_csv, 1, repr(err.value))
    assert "shoulder_lift" in err.value and "shoulder_lift" in msg
    assert "missing ['lbr_iiwa_joint_3']" in msg and "unexpected ['shoulder_lift']" in msg


def test_joints_header_mismatch_stops_even_with_skip_bad(rec):
    """A bad header is a problem of the whole file, not of one frame: it is never silently skipped."""
    joints_csv = rec / "joints.csv"
    joints_csv.write_text(joints_csv.read_text().replace("lbr_iiwa_joint_3", "shoulder_lift", 1))
    with pytest.raises(RecordingError, match="shoulder_lift"):
        label(rec, skip_bad=True)


def test_unknown_robot_type(rec):
    meta_path = rec / "recording.json"
    raw = json.loads(meta_path.read_text())
    raw["robot"] = "r2d2"
    meta_path.write_text(json.dumps(raw))
    with pytest.raises(RecordingError) as info:
        label(rec)
    msg = assert_names(info.value, meta_path, None, "'r2d2'")
    assert "unknown robot type" in msg and "iiwa" in msg  # lists the known types


def test_non_unit_quaternion(rec):
    poses_csv = rec / "camera_poses.csv"
    set_cell(poses_csv, 3, "qw", "1.5")  # line 3 = frame 1
    with pytest.raises(RecordingError) as info:
        label(rec)
    err = info.value
    assert err.value[3] == 1.5
    msg = assert_names(err, poses_csv, 3, repr(err.value))
    assert "1.5" in msg and "not unit" in msg


@pytest.mark.parametrize("key, value, problem", [
    ("fx", -50.0, "fx must be a positive number"), ("fy", float("nan"), "fy must be a positive number"),
    ("width", 64.9, "width must be a whole number"), ("height", 0, "height must be a positive number"),
    ("cx", "239.5", "cx must be a positive number")])
def test_a_camera_that_is_not_a_pinhole_camera_is_refused_naming_the_key(rec, key, value, problem):
    meta_path = rec / "recording.json"
    raw = json.loads(meta_path.read_text())
    raw["camera"][key] = value
    meta_path.write_text(json.dumps(raw))
    with pytest.raises(RecordingError) as info:
        label(rec)
    msg = assert_names(info.value, meta_path, None, repr(value))
    assert problem in msg


def test_a_robot_that_is_not_a_name_is_refused(rec):
    meta_path = rec / "recording.json"
    raw = json.loads(meta_path.read_text())
    raw["robot"] = ["iiwa"]
    meta_path.write_text(json.dumps(raw))
    with pytest.raises(RecordingError) as info:
        label(rec)
    assert "robot must be a robot type name" in assert_names(info.value, meta_path, None, "['iiwa']")


def test_a_frame_listed_twice_names_both_lines(rec):
    joints_csv = rec / "joints.csv"
    lines = joints_csv.read_text().splitlines()
    joints_csv.write_text("\n".join(lines + [lines[2]]) + "\n")     # frame 1 again, on line 5
    with pytest.raises(RecordingError) as info:
        label(rec)
    assert "frame listed twice (first on line 3)" in assert_names(info.value, joints_csv, 5, "1")
    arrays, _, skipped = label(rec, skip_bad=True)                    # the first reading is kept
    assert arrays["frame"].tolist() == list(range(NUM_FRAMES)) and len(skipped) == 1


def test_a_frame_index_that_is_not_an_integer_is_a_row_error(rec):
    joints_csv = rec / "joints.csv"
    set_cell(joints_csv, 3, "frame", "1.5")
    with pytest.raises(RecordingError) as info:
        label(rec)
    assert "frame index is not an integer" in assert_names(info.value, joints_csv, 3, "'1.5'")
    arrays, _, skipped = label(rec, skip_bad=True)
    assert 1 not in arrays["frame"].tolist() and skipped


def test_a_recording_without_rows_and_a_csv_that_is_not_text_are_errors(rec):
    joints_csv = rec / "joints.csv"
    for table in (joints_csv, rec / "camera_poses.csv"):
        table.write_text(table.read_text().splitlines()[0] + "\n")     # the header alone
    header = joints_csv.read_text().splitlines()[0]
    with pytest.raises(RecordingError, match="no rows"):
        label(rec)
    joints_csv.write_bytes(b"\xff\xfe" + header.encode("utf-16-le"))
    with pytest.raises(RecordingError) as info:
        label(rec)
    assert str(joints_csv) in str(info.value) and "not a UTF-8 text CSV file" in str(info.value)


def test_quaternion_within_tolerance_is_accepted(rec):
    poses_csv = rec / "camera_poses.csv"
    _, poses, _ = read_poses(rec)
    set_cell(poses_csv, 2, "qw", repr(float(poses[0, 6]) + 2e-4))  # rounding, as a 4-decimal CSV would give
    frames, _, errors = read_poses(rec)
    assert errors == [] and frames.tolist() == list(range(NUM_FRAMES))


# --------------------------------------------------------------------------- skip_bad

def _missing_png(rec):
    frame_path(rec, 1).unlink()
    return "000001.png"


def _corrupt_png(rec):
    frame_path(rec, 1).write_bytes(b"\x89PNG garbage, not an image")
    return "000001.png"


def _wrong_size(rec):
    write_frame(rec, 1, random_image(1, Camera(320, 240, 1, 1, 0, 0)))
    return "320x240"


def _nan_joint(rec):
    set_cell(rec / "joints.csv", 3, "lbr_iiwa_joint_2", "nan")
    return "joints.csv:3"


def _empty_joint(rec):
    set_cell(rec / "joints.csv", 3, "lbr_iiwa_joint_6", "")
    return "joints.csv:3"


def _non_unit_quat(rec):
    set_cell(rec / "camera_poses.csv", 3, "qx", "0.9")
    return "camera_poses.csv:3"


@pytest.mark.parametrize("corrupt", [_missing_png, _corrupt_png, _wrong_size, _nan_joint, _empty_joint,
                                     _non_unit_quat], ids=lambda f: f.__name__.strip("_"))
def test_skip_bad_labels_good_frames_and_reports_bad(rec, corrupt, caplog):
    good, _, _ = label(rec)
    marker = corrupt(rec)
    with pytest.raises(RecordingError, match=marker):
        label(rec)
    with caplog.at_level(logging.WARNING, logger="armpose.labels.compute"):
        arrays, meta, skipped = label(rec, skip_bad=True)
    # the good frames are labelled, exactly as without the bad one
    assert arrays["frame"].tolist() == [0, 2]
    keep = [0, 2]
    for key in ("images", "masks", "joints", "joint_valid", "base", "distance", "intrinsics"):
        assert arrays[key].shape[0] == 2, key
        np.testing.assert_array_equal(arrays[key], good[key][keep], err_msg=key)
    assert np.isfinite(arrays["joints"]).all()
    # the bad one is counted and reported, naming where it is ...
    assert len(skipped) == 1 and marker in skipped[0]
    # ... and logged
    logged = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert any("skipped" in m and marker in m for m in logged), logged


def test_skip_bad_reports_every_bad_frame(rec, caplog):
    frame_path(rec, 0).unlink()
    set_cell(rec / "joints.csv", 4, "lbr_iiwa_joint_1", "")  # frame 2
    with caplog.at_level(logging.WARNING, logger="armpose.labels.compute"):
        arrays, _, skipped = label(rec, skip_bad=True)
    assert arrays["frame"].tolist() == [1]
    assert len(skipped) == 2
    assert any("000000.png" in s for s in skipped) and any("joints.csv:4" in s for s in skipped)
    assert sum("skipped" in r.getMessage() for r in caplog.records) == 2


def test_blank_lines_do_not_shift_rows(tmp_path):
    """Blank lines in a CSV are ignored, but errors still name the file's own line, and
    with skip_bad exactly the bad frames are dropped (not their neighbours)."""
    rec = make_recording(tmp_path / "rec", n=4)
    for name in ("joints.csv", "camera_poses.csv"):
        path = rec / name
        lines = path.read_text().splitlines()
        path.write_text("\n".join(lines[:2] + [""] + lines[2:]) + "\n\n")  # blank after frame 0, and at the end
    set_cell(rec / "joints.csv", 5, "lbr_iiwa_joint_2", "nan")   # line 5 = frame 2
    set_cell(rec / "camera_poses.csv", 4, "qw", "2.0")            # line 4 = frame 1
    with pytest.raises(RecordingError) as info:
        label(rec)
    assert_names(info.value, rec / "joints.csv", 5, "'nan'")
    _, _, errors = read_poses(rec)
    assert [e.row for e in errors] == [4] and errors[0].value[3] == 2.0
    arrays, _, skipped = label(rec, skip_bad=True)
    assert arrays["frame"].tolist() == [0, 3]
    assert np.isfinite(arrays["joints"]).all() and np.isfinite(arrays["base"]).all()
    assert len(skipped) == 2
    assert any("joints.csv:5:" in s for s in skipped) and any("camera_poses.csv:4:" in s for s in skipped)


def test_skip_bad_with_every_frame_bad_gives_empty_arrays(rec):
    for f in range(NUM_FRAMES):
        frame_path(rec, f).unlink()
    arrays, _, skipped = label(rec, skip_bad=True)
    assert len(skipped) == NUM_FRAMES
    assert arrays["frame"].shape == (0,)
    assert arrays["images"].shape == (0, 48, 64, 3) and arrays["joints"].shape == (0, MAX_JOINTS, 3)


# --------------------------------------------------------------------------- the stage

def stage_params(skip_bad: bool = False) -> dict:
    params = profile_params("quick")
    params["labels"]["recordings"] = ["recs"]
    params["labels"]["skip_bad"] = skip_bad
    params["base"]["num_workers"] = 1
    return params


def snapshot(out: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(out.iterdir())}


def test_stage_failure_leaves_no_complete_looking_dataset(tmp_path):
    root = tmp_path
    labels_dir = root / "data" / "labels"
    make_recording(root / "recs" / "rec_a")
    rec_b = make_recording(root / "recs" / "rec_b")
    frame_path(rec_b, 1).write_bytes(b"not a png")

    # 1. a failed first run leaves no index.json
    with pytest.raises(RecordingError, match="000001.png"):
        labels_stage.run(stage_params(), root)
    assert not (labels_dir / "index.json").exists()
    with pytest.raises(FileNotFoundError):
        load_dataset(labels_dir)

    # 2. fixed, the run completes
    write_frame(rec_b, 1, random_image(1))
    res = labels_stage.run(stage_params(), root)
    assert res["frames"] == 2 * NUM_FRAMES and res["skipped"] == 0
    before = snapshot(labels_dir)
    index = json.loads(before["index.json"])
    assert index["num_frames"] == 2 * NUM_FRAMES and index["num_skipped"] == 0
    assert {r["name"] for r in index["recordings"]} == {"recs/rec_a", "recs/rec_b"}
    assert set(before) == {f"{name}.npy" for name in ARRAYS} | {"index.json"}

    # 3. a later failing run (NaN joint) leaves the complete dataset as it was
    set_cell(rec_b / "joints.csv", 2, "lbr_iiwa_joint_5", "nan")
    with pytest.raises(RecordingError) as info:
        labels_stage.run(stage_params(), root)
    assert_names(info.value, rec_b / "joints.csv", 2, "'nan'")
    assert snapshot(labels_dir) == before
    arrays, idx = load_dataset(labels_dir)
    assert idx == index and arrays["frame"].shape == (2 * NUM_FRAMES,)

    # 4. so does a run that fails while writing the dataset itself
    set_cell(rec_b / "joints.csv", 2, "lbr_iiwa_joint_5", "0.1")
    real_save = dataset_mod.atomic_save_npy
    calls = []

    def failing_save(path, array):
        calls.append(path)
        if len(calls) == 3:
            raise OSError("disk full")
        real_save(path, array)

    mp = pytest.MonkeyPatch()
    mp.setattr(dataset_mod, "atomic_save_npy", failing_save)
    try:
        with pytest.raises(OSError, match="disk full"):
            labels_stage.run(stage_params(), root)
    finally:
        mp.undo()
    assert len(calls) == 3
    assert snapshot(labels_dir) == before
    # the half-written folder is beside it, without an index, and is not what readers open
    assert not (root / "data" / ".labels.tmp" / "index.json").exists()

    # 5. and the next good run replaces it all
    res = labels_stage.run(stage_params(), root)
    assert res["frames"] == 2 * NUM_FRAMES
    assert not (root / "data" / ".labels.tmp").exists() and not (root / "data" / ".labels.old").exists()


def test_stage_skip_bad_counts_skipped_frames(tmp_path):
    root = tmp_path
    make_recording(root / "recs" / "rec_a")
    rec_b = make_recording(root / "recs" / "rec_b")
    frame_path(rec_b, 2).unlink()
    set_cell(rec_b / "camera_poses.csv", 2, "qz", "0.7")  # frame 0

    res = labels_stage.run(stage_params(skip_bad=True), root)
    index = json.loads((root / "data" / "labels" / "index.json").read_text())
    assert res["skipped"] == 2 and index["num_skipped"] == 2
    assert index["num_frames"] == 2 * NUM_FRAMES - 2 == res["frames"]
    frames = {r["name"]: r["frames"] for r in index["recordings"]}
    assert frames == {"recs/rec_a": NUM_FRAMES, "recs/rec_b": NUM_FRAMES - 2}
    assert any("000002.png" in s for s in index["skipped"])
    assert any("camera_poses.csv:2" in s for s in index["skipped"])
    arrays, _ = load_dataset(root / "data" / "labels")
    assert arrays["frame"][arrays["recording"] == 1].tolist() == [1]
