"""Stage ``record``: simulated handheld- and tripod-camera sessions with a mocap rig (deterministic,
resumable, realistic calibration error that the labels carry), and real recordings validated and linked."""
from __future__ import annotations

import copy
import json
import os
import shutil

import numpy as np
import pybullet as pb
import pytest

from armpose.config import profile_params
from armpose.geometry import Camera, invert
from armpose.labels.compute import label_recording
from armpose.labels.mask import mask_renderer
from armpose.labels.quality import joints_near_mask
from armpose.recording import (
    RecordingError,
    find_recordings,
    read_joints,
    read_meta,
    read_poses,
    static_camera,
)
from armpose.robots import get_robot
from armpose.sim.body import RobotBody
from armpose.sessions.motion import camera_orbit, in_view, robot_motion, tripod_camera
from armpose.sessions.session import read_true_poses, session_errors
from armpose.stages import record

FRAMES = 4
#: a complete, tiny ``record`` section (the profiles' own is checked by the notebook test)
RECORD = {
    "recordings_dir": None,
    "sessions_per_robot": {"iiwa": 1},
    "frames_per_session": FRAMES,
    "fps": 30.0,
    "camera": {"distance": [1.2, 3.0], "elevation_deg": [0.0, 40.0], "max_height": 2.0,
               "walk_speed": [0.1, 0.6], "follow_s": 0.5, "lookat_jitter": 0.08, "roll_deg": 6.0,
               "shake": {"translation_mm": 4.0, "rotation_deg": 0.4, "hz": [1.0, 3.0]}, "min_in_view": 0.9},
    "robot": {"segment_s": [1.0, 2.5], "max_joint_speed": 1.5},
    "rig": {"offset_translation_m": [0.03, 0.08], "offset_rotation_deg": [5.0, 20.0],
            "mocap_noise": {"translation_mm": 0.5, "rotation_deg": 0.1}, "calibration_views": 8},
    "randomize": {
        "background": {"enabled": True, "textures": 2, "table_prob": 0.6, "table_height": [0.6, 0.9],
                       "walls": [1, 2], "distractors": [0, 3], "other_robot_prob": 0.0},
        "lighting": {"enabled": True, "ambient": [0.25, 0.8], "diffuse": [0.3, 0.9], "specular": [0.0, 0.5],
                     "color_jitter": 0.25, "shadow_prob": 0.0},
        "camera_noise": {"enabled": True, "gain": [0.75, 1.25], "offset": [-20.0, 20.0], "gaussian_std": [0.0, 6.0],
                         "blur_prob": 0.3, "blur_sigma": [0.5, 1.5]},
        "robot_appearance": {"enabled": True, "color_jitter": 0.05},
    },
}


def _params(**record) -> dict:
    params = profile_params("quick")
    params["base"]["num_workers"] = 1
    params["record"] = {**copy.deepcopy(RECORD), **record}
    return params


def _files(folder) -> dict:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The same tiny session simulated into two project roots."""
    roots = [tmp_path_factory.mktemp(name) for name in ("a", "b")]
    results = [record.run(_params(), root) for root in roots]
    return roots, results


@pytest.fixture(scope="module")
def session(runs):
    _, results = runs
    (rec,) = results[0]["recordings"]
    return rec


def test_same_seed_gives_identical_sessions(runs):
    (a, b), results = runs
    assert results[0]["new"] == 1 and results[0]["frames"] == FRAMES
    files_a, files_b = _files(a / "data" / "record"), _files(b / "data" / "record")
    assert len([f for f in files_a if f.endswith(".png")]) == FRAMES
    assert files_a.keys() == files_b.keys() and "summary.json" in files_a
    for name in files_a:
        assert files_a[name] == files_b[name], name


def test_recording_is_recorded_simulated_and_calibrated(session):
    meta, spec = read_meta(session)
    assert meta.source == "recorded" and session.name == "iiwa_s00" and session.parent.name == "iiwa"
    raw = json.loads((session / "recording.json").read_text())
    assert raw["simulated"] is True and "SIMULATED" in raw["notes"]
    err = raw["simulation"]["rig_offset_error"]
    print(f"rig calibration error: {err['translation_mm']:.3f} mm, {err['rotation_deg']:.4f} deg")
    assert 0 < err["translation_mm"] < 3.0 and 0 < err["rotation_deg"] < 0.3   # a few mm, tenths of a degree
    cal = raw["rig_calibration"]
    assert cal["views_given"] == 8 and cal["views_used"] >= 6 and 0 < cal["rms_reprojection_px"] < 2.0
    assert {"translation_mm", "rotation_deg", "reprojection_px", "status"} <= set(cal["views"][0])
    summary = json.loads((session.parents[1] / "summary.json").read_text())
    assert summary["mode"] == "simulated" and summary["num_frames"] == FRAMES
    assert summary["sessions"][0]["rig_offset_error"] == err
    assert read_joints(session, spec)[2] == [] and read_poses(session)[2] == []


def test_written_poses_carry_the_calibration_and_mocap_error(session):
    _, poses, _ = read_poses(session)
    true = read_true_poses(session)
    assert len(true) == len(poses) == FRAMES
    err = session_errors(session)
    print({k: np.round(v, 3).tolist() for k, v in err.items()})
    assert (err["camera_translation_mm"] > 0.05).all() and (err["camera_translation_mm"] < 15.0).all()
    assert (err["camera_rotation_deg"] > 0.0).all() and (err["camera_rotation_deg"] < 0.6).all()
    assert (err["joint_reprojection_px"] > 0.0).all() and (err["joint_reprojection_px"] < 5.0).all()


def test_labels_still_project_onto_the_robot(session):
    params = _params()
    arrays, meta, skipped = label_recording(session, params["base"]["input_size"], params["base"]["max_joints"])
    assert not skipped and len(arrays["frame"]) == FRAMES
    on_mask = joints_near_mask(arrays["masks"], arrays["joints"], arrays["joint_valid"], arrays["intrinsics"])
    assert on_mask.mean() == 1.0
    # the label mask (written pose) against the robot where it really is (true pose): nearly the same pixels
    cam_in = meta.camera.scale_crop(params["base"]["input_size"]["width"], params["base"]["input_size"]["height"])[0]
    _, q, _ = read_joints(session, get_robot(meta.robot))
    renderer = mask_renderer(get_robot(meta.robot))
    for i, T in enumerate(read_true_poses(session)):
        true_mask = renderer.render(q[i], T, cam_in)
        label = arrays["masks"][i].astype(bool)
        assert true_mask.sum() > 100
        assert (true_mask & label).sum() / (true_mask | label).sum() > 0.85


def test_resume_skips_finished_sessions_and_leaves_nothing_half_written(runs, monkeypatch):
    (a, _), _ = runs
    rec = a / "data" / "record" / "iiwa" / "iiwa_s00"
    before = {p: p.stat().st_mtime_ns for p in rec.rglob("*")}
    leftover = rec.parent / ".iiwa_s01.crashed"          # an interrupted run's temporary folder
    (leftover / "frames").mkdir(parents=True)
    (leftover / "recording.json").write_text("{}")
    res = record.run(_params(), a)
    assert res["new"] == 0 and not leftover.exists()
    assert {p: p.stat().st_mtime_ns for p in rec.rglob("*")} == before

    def crash(*args, **kwargs):
        raise RuntimeError("killed while writing the tables")
    monkeypatch.setattr("armpose.sessions.session.write_tables", crash)
    params = _params(frames_per_session=2, sessions_per_robot={"iiwa": 2})
    params["record"]["rig"]["calibration_views"] = 4
    with pytest.raises(RuntimeError, match="killed"):
        record.run(params, a)
    # the crashed rewrite of iiwa_s00 (now a 2-frame job) left the old recording as it was, and the
    # crashed iiwa_s01 left no folder that looks like a recording, and no temporary folder
    assert find_recordings(a / "data" / "record") == [rec]
    assert not [p for p in rec.parent.iterdir() if p.name.startswith(".")]


def _real_copy(session, folder):
    dst = folder / "lab1" / "run1"
    shutil.copytree(session, dst)
    return dst


def test_real_recordings_are_validated_and_linked(session, tmp_path):
    real = tmp_path / "real"
    src = _real_copy(session, real)
    root = tmp_path / "root"
    stale = root / "data" / "record" / "iiwa" / "iiwa_s00"   # a simulated session from before
    shutil.copytree(session, stale)
    res = record.run(_params(recordings_dir=str(real)), root)
    (dst,) = res["recordings"]
    assert dst == root / "data" / "record" / "iiwa" / "lab1__run1" and not stale.exists()
    assert res["new"] == 1 and res["summary"]["mode"] == "linked" and res["frames"] == FRAMES
    assert os.stat(dst / "frames" / "000000.png").st_ino == os.stat(src / "frames" / "000000.png").st_ino
    meta = json.loads((dst / "recording.json").read_text())
    assert meta["record_import"]["mode"] == "hard link" and meta["source"] == "recorded"
    assert record.run(_params(recordings_dir=str(real)), root)["new"] == 0


@pytest.mark.parametrize("damage, message", [
    (lambda rec: _replace_line(rec / "camera_poses.csv", 3, lambda cells: cells[:4] + ["0.9", "0.1", "0.1", "0.1"]),
     "camera_poses.csv:3: quaternion is not unit"),
    (lambda rec: (rec / "frames" / "000002.png").unlink(), "000002.png: frame image is missing"),
    (lambda rec: _replace_line(rec / "joints.csv", 2, lambda cells: cells[:2] + ["nan"] + cells[3:]),
     "joints.csv:2: lbr_iiwa_joint_2 is missing or not a finite number"),
])
def test_a_bad_real_recording_is_rejected_naming_the_file(session, tmp_path, damage, message):
    real = tmp_path / "real"
    damage(_real_copy(session, real))
    with pytest.raises(RecordingError) as err:
        record.run(_params(recordings_dir=str(real)), tmp_path / "root")
    assert message in str(err.value) and str(real) in str(err.value)
    assert not find_recordings(tmp_path / "root" / "data" / "record")


def test_two_recordings_that_would_share_a_folder_are_refused(session, tmp_path):
    real = tmp_path / "real"
    _real_copy(session, real)                                       # real/lab1/run1 -> lab1__run1
    shutil.copytree(real / "lab1" / "run1", real / "lab1__run1")    # real/lab1__run1 -> lab1__run1 too
    with pytest.raises(RecordingError, match="same folder as"):
        record.run(_params(recordings_dir=str(real)), tmp_path / "root")
    assert not find_recordings(tmp_path / "root" / "data" / "record")


def _replace_line(path, line: int, edit) -> None:
    lines = path.read_text().splitlines()
    lines[line - 1] = ",".join(edit(lines[line - 1].split(",")))
    path.write_text("\n".join(lines) + "\n")


def test_unknown_robot_in_sessions_is_an_error(tmp_path):
    with pytest.raises(ValueError, match="'r2d2'.*not in base.robot_types"):
        record.run(_params(sessions_per_robot={"r2d2": 1}), tmp_path)


def test_camera_orbit_is_smooth_and_keeps_the_robot_in_view():
    camera = Camera.from_dict(profile_params("quick")["base"]["camera"])
    rng = np.random.default_rng(0)
    n, fps = 90, 30.0
    t = np.arange(n)[:, None] / fps
    points = np.stack([np.zeros((n, 3)), np.hstack([0.3 * np.cos(t), 0.3 * np.sin(t), 0.5 + 0 * t]),
                       np.hstack([0.5 * np.cos(t), 0.5 * np.sin(t), 0.8 + 0.1 * t])], axis=1)   # a moving "robot"
    for _ in range(5):
        T = camera_orbit(points, camera, RECORD["camera"], rng, fps)
        dist = np.linalg.norm(T[:, :3, 3] - points.reshape(-1, 3).mean(axis=0), axis=1)
        assert (dist > 1.1).all() and (dist < 3.1).all()
        step = invert(T[:-1]) @ T[1:]
        move_mm = 1000 * np.linalg.norm(step[:, :3, 3], axis=1)
        turn_deg = np.degrees(np.arccos(np.clip((np.trace(step[:, :3, :3], axis1=1, axis2=2) - 1) / 2, -1, 1)))
        assert move_mm.max() < 40 and turn_deg.max() < 2.0            # smooth at 30 Hz
        assert np.abs(np.diff(move_mm)).max() < 10                     # no jerks either
        assert in_view(points, T, camera).mean() > 0.8


def test_robot_motion_is_smooth_within_limits_and_collision_free():
    spec = get_robot("iiwa")
    client = pb.connect(pb.DIRECT)
    try:
        body = RobotBody(client, spec, self_collision=True)
        floor = pb.createMultiBody(0, pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[3, 3, 0.05],
                                                              physicsClientId=client), -1, [0, 0, -0.05],
                                   physicsClientId=client)
        q = robot_motion(body, floor, np.random.default_rng(1), 90, 30.0, RECORD["robot"])
        lim = np.array(spec.joint_limits)
        assert q.shape == (90, 7) and ((q >= lim[:, 0]) & (q <= lim[:, 1])).all()
        speed = np.abs(np.diff(q, axis=0)) * 30.0
        assert speed.max() <= 1.5 * 1.02 and np.abs(q[-1] - q[0]).max() > 0.2   # moves, not too fast
        for qi in q:
            body.set_joints(qi)
            assert not body.in_collision([floor])
    finally:
        pb.disconnect(client)


@pytest.fixture(scope="module")
def tripod(tmp_path_factory):
    """One tiny tripod session (no handheld ones)."""
    root = tmp_path_factory.mktemp("tripod")
    res = record.run(_params(sessions_per_robot={}, tripod_sessions_per_robot={"iiwa": 1}), root)
    (rec,) = res["recordings"]
    return rec


def test_tripod_session_has_a_static_camera_and_a_moving_robot(tripod, session):
    assert tripod.name == "iiwa_t00" and tripod.parent.name == "iiwa"
    raw = json.loads((tripod / "recording.json").read_text())
    assert raw["session"]["kind"] == "tripod" and raw["source"] == "recorded" and "tripod" in raw["notes"]
    true = read_true_poses(tripod)
    assert len(true) == FRAMES and np.abs(true - true[0]).max() == 0.0          # the camera never moves
    _, poses, _ = read_poses(tripod)
    assert np.abs(poses - poses[0]).max() == 0.0                                 # measured once: static as written
    err = session_errors(tripod)
    assert 0.05 < err["camera_translation_mm"][0] < 15.0                          # one constant calibration error
    assert np.ptp(err["camera_translation_mm"]) < 1e-9
    _, q, _ = read_joints(tripod, get_robot("iiwa"))
    assert np.abs(q[-1] - q[0]).max() > 0.0                                      # while the robot moves
    assert static_camera(tripod) and not static_camera(session)
    summary = json.loads((tripod.parents[1] / "summary.json").read_text())
    assert summary["sessions"][0]["kind"] == "tripod"


def test_plan_names_and_seeds_handheld_and_tripod_sessions_apart(tmp_path):
    params = _params(sessions_per_robot={"iiwa": 2}, tripod_sessions_per_robot={"iiwa": 1, "panda": 1})
    jobs = record.plan(params, tmp_path)
    assert [(j.out_dir.name, j.kind) for j in jobs] == [("iiwa_s00", "handheld"), ("iiwa_s01", "handheld"),
                                                        ("iiwa_t00", "tripod"), ("panda_t00", "tripod")]
    assert len({j.seed for j in jobs}) == len(jobs) and len({j.signature() for j in jobs}) == len(jobs)
    with pytest.raises(ValueError, match="tripod_sessions_per_robot names \\['r2d2'\\]"):
        record.plan(_params(tripod_sessions_per_robot={"r2d2": 1}), tmp_path)


def test_tripod_camera_is_static_and_keeps_the_robot_in_view():
    camera = Camera.from_dict(profile_params("quick")["base"]["camera"])
    n, fps = 60, 30.0
    t = np.arange(n)[:, None] / fps
    points = np.stack([np.zeros((n, 3)), np.hstack([0.3 * np.cos(t), 0.3 * np.sin(t), 0.5 + 0 * t]),
                       np.hstack([0.5 * np.cos(t), 0.5 * np.sin(t), 0.8 + 0.1 * t])], axis=1)
    for seed in range(5):
        T, frac = tripod_camera(points, camera, RECORD["camera"], np.random.default_rng(seed))
        assert T.shape == (n, 4, 4) and np.abs(T - T[0]).max() == 0.0
        assert frac >= RECORD["camera"]["min_in_view"] and in_view(points, T, camera).mean() == frac
        dist = np.linalg.norm(T[0, :3, 3] - points.reshape(-1, 3).mean(axis=0))
        assert 1.2 - 1e-9 <= dist <= 3.0 + 1e-9 and T[0, 2, 3] <= 2.0
