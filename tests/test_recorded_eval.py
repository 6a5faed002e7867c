"""Recorded test data: the per-robot split rule, pooled camera-to-robot pose over a static camera,
raw against filtered sequence metrics, and their results-table sections."""
from __future__ import annotations

import math
import zlib

import numpy as np
import pytest

from armpose.camera_pose import robust_rigid
from armpose.geometry import invert
from armpose.labels.dataset import SOURCE_CODES, recorded_test_names, split_for
from armpose.pose_eval import pooled_errors, pose_errors, spread_chunks
from armpose.report import camera_pose_section, recording_section, sequence_section, source_section
from armpose.robots import get_robot
from armpose.robots.kinematics import Kinematics
from armpose.sequence_eval import metrics_by_recording, sequence_errors, sequence_metrics

# --------------------------------------------------------------------------- split

def _recordings(counts: dict[str, int], tripods: dict[str, int]) -> list[dict]:
    recs = [{"name": f"data/record/{r}/{r}_s{k:02d}", "robot": r, "static_camera": False}
            for r, n in counts.items() for k in range(n)]
    return recs + [{"name": f"data/record/{r}/{r}_t{k:02d}", "robot": r, "static_camera": True}
                   for r, n in tripods.items() for k in range(n)]


def test_every_robot_gets_recorded_test_recordings_and_every_tripod_is_test():
    recs = _recordings({"ur3": 1, "ur5": 2, "iiwa": 5, "panda": 20}, {"ur5": 1, "panda": 2})
    test = recorded_test_names(recs, 2019, 0.2)
    for robot, n in {"ur3": 1, "ur5": 2, "iiwa": 5, "panda": 20}.items():
        moving = {r["name"] for r in recs if r["robot"] == robot and not r["static_camera"]}
        assert len(moving & test) == math.ceil(0.2 * n) >= 1, robot
    assert {r["name"] for r in recs if r["static_camera"]} <= test
    assert test == recorded_test_names(list(reversed(recs)), 2019, 0.2)          # order does not matter
    draws = {frozenset(recorded_test_names(recs, seed, 0.2)) for seed in range(10)}
    assert len(draws) > 1                                                         # the seed picks them


def test_synthetic_split_is_the_old_per_frame_draw():
    for name, n, seed in (("data/render/ur5/ur5_000", 2000, 2019), ("data/render/panda/panda_003", 100, 7)):
        rng = np.random.default_rng([seed, 2, zlib.crc32(name.encode())])
        old = (rng.uniform(size=n) < 0.2).astype(np.uint8)
        np.testing.assert_array_equal(split_for(name, n, seed, 0.2), old)


# --------------------------------------------------------------------------- pooled pose

def test_spread_chunks_spread_groups_over_the_sequence():
    groups = spread_chunks(90, 10)
    assert len(groups) == 9 and all(len(g) == 10 for g in groups)
    assert groups[0].tolist() == list(range(0, 90, 9)) and len(np.unique(np.concatenate(groups))) == 90
    assert [g.tolist() for g in spread_chunks(4, 10)] == [[0, 1, 2, 3]] and spread_chunks(0, 10) == []


def _static_scene(frames: int, seed: int):
    """FK points of a UR5 moving in front of one static camera: (points_base list, T_cam_base)."""
    rng = np.random.default_rng(seed)
    spec = get_robot("ur5")
    lim = np.array(spec.joint_limits)
    q = rng.uniform(np.maximum(lim[:, 0], -2.5), np.minimum(lim[:, 1], 2.5), (frames, len(lim)))
    joints = Kinematics(spec).joint_positions(q)
    src = [np.vstack([np.zeros(3), j]) for j in joints]
    T_base_cam = np.eye(4)
    T_base_cam[:3, :3] = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # looking along -x
    T_base_cam[:3, 3] = [2.0, 0.3, 0.6]
    return src, invert(T_base_cam)


def test_pooled_pose_is_exact_on_true_points_and_beats_single_images_on_noisy_ones():
    src, T = _static_scene(40, 0)
    exact = [(T[:3, :3] @ p.T).T + T[:3, 3] for p in src]
    e = pooled_errors(src, exact, T, 10)
    assert len(e["rot_deg"]) == 4
    assert e["rot_deg"].max() < 1e-4 and e["trans_m"].max() < 1e-6 and e["add_m"].max() < 1e-6
    rng = np.random.default_rng(1)
    noisy = [p + rng.normal(0, 0.02, p.shape) for p in exact]
    pooled = pooled_errors(src, noisy, T, 10)
    single = np.array([pose_errors(robust_rigid(s, d, method="huber").T, T, s) for s, d in zip(src, noisy)])
    print(f"ADD median: pooled {100 * np.median(pooled['add_m']):.2f} cm, single {100 * np.median(single[:, 2]):.2f} cm")
    assert np.median(pooled["add_m"]) < 0.6 * np.median(single[:, 2])
    assert np.median(pooled["rot_deg"]) < np.median(single[:, 0])
    assert np.median(pooled["trans_m"]) < np.median(single[:, 1])


# --------------------------------------------------------------------------- sequences

def test_filters_cut_jitter_of_a_noisy_constant_signal():
    rng = np.random.default_rng(0)
    labels = np.repeat(np.array([[0.1, 0.2, 2.0], [0.3, -0.1, 2.2]])[None], 90, axis=0)
    raw = labels + rng.normal(0, 0.02, labels.shape)
    e = sequence_errors(raw, labels, np.arange(90) / 30.0, ["kalman", "one-euro"], 30.0)
    assert e["labels"]["jitter_m"] == 0.0
    for f in ("kalman", "one-euro"):
        assert e["unfiltered"]["jitter_m"] > 2.0 * e[f]["jitter_m"], f
        assert np.median(e[f]["dist_m"]) < np.median(e["unfiltered"]["dist_m"]), f


def _fake_split(rng):
    """Two recorded test recordings (one static camera, 30 frames each) and a synthetic frame."""
    n = 61
    truth = {"source": np.r_[np.full(60, SOURCE_CODES["recorded"]), SOURCE_CODES["synthetic"]],
             "recording": np.r_[np.zeros(30, int), np.ones(30, int), 2], "row": np.arange(n),
             "type": np.r_[np.full(30, 4), np.zeros(31, int)],
             "joints": np.repeat(rng.normal(0, 0.3, (1, 7, 3)) + [0, 0, 2], n, axis=0),
             "joint_valid": np.tile(np.r_[np.ones(6, bool), False], (n, 1))}
    arrays = {"frame": np.r_[np.arange(30)[::-1], np.arange(30), 0]}            # recording 0 stored out of order
    index = {"recordings": [{"name": "a", "robot": "panda", "static_camera": True},
                            {"name": "b", "robot": "ur3", "static_camera": False},
                            {"name": "c", "robot": "ur3", "static_camera": False}]}
    return truth, arrays, index


def test_sequence_metrics_per_family_and_camera_with_the_jitter_reduction():
    rng = np.random.default_rng(2)
    truth, arrays, index = _fake_split(rng)
    pred = {"joints": truth["joints"] + rng.normal(0, 0.02, truth["joints"].shape)}
    fams = ["UR", "UR", "UR", "KUKA", "Panda"]
    m = sequence_metrics(pred, truth, index, arrays, fams, 30.0, ["kalman"])
    a = m["all"]
    assert a["recordings"] == 2 and a["frames"] == 60 and set(m["by_family"]) == {"Panda", "UR"}
    assert set(m["by_camera"]) == {"static", "moving"} and m["by_camera"]["static"]["recordings"] == 1
    assert a["kalman"]["jitter_reduction"] > 2.0 and 50 < a["kalman"]["jitter_reduction_pct"] < 100
    assert a["kalman"]["jitter_mm"] < a["unfiltered"]["jitter_mm"]
    lines = "\n".join(sequence_section(m))
    assert "Jitter reduction" in lines and "kalman" in lines and "static camera" in lines


def test_metrics_by_recording_find_the_recording_placed_too_close():
    truth, arrays, index = _fake_split(np.random.default_rng(3))
    n = len(truth["type"])
    truth.update(base=truth["joints"][:, 0].copy(), intrinsics=np.tile([300.0, 300.0, 128.0, 106.0], (n, 1)))
    joints = truth["joints"].copy()
    joints[:30] *= 0.8                                   # recording 0: every point 20 % nearer the camera
    pred = {"joints": joints, "base": joints[:, 0].copy(), "type": truth["type"].copy(),
            "mask_counts": np.tile([95, 5, 5, 100], (n, 1))}
    pred["type"][30:40] = 1                              # recording 1: a third typed wrong
    m = metrics_by_recording(pred, truth, index, arrays, 1.0)
    assert list(m) == ["a", "b"]                         # recorded test recordings only, not the synthetic frame
    a, b = m["a"], m["b"]
    assert a["camera"] == "static" and b["camera"] == "moving" and a["frames"] == b["frames"] == 30
    assert a["frame_depth_ratio_median"] == pytest.approx(0.8) and b["frame_depth_ratio_median"] == pytest.approx(1.0)
    assert a["joint_median_cm"] > 30 and a["joint_median_true_depth_cm"] == pytest.approx(0.0, abs=1e-6)
    assert b["joint_median_cm"] == pytest.approx(0.0, abs=1e-6)
    assert a["type_accuracy"] == 1.0 and b["type_accuracy"] == pytest.approx(2 / 3)
    text = "\n".join(recording_section(m))
    assert "| a | " in text and "| 0.800 |" in text and "| 66.7 |" in text
    assert recording_section({}) == []


def test_no_recorded_test_data_gives_empty_sections():
    truth, arrays, index = _fake_split(np.random.default_rng(0))
    truth["source"][:] = SOURCE_CODES["synthetic"]
    m = sequence_metrics({"joints": truth["joints"]}, truth, index, arrays, ["UR"] * 5, 30.0, ["kalman"])
    assert m["all"] == {"recordings": 0} and sequence_section(m) == []
    assert source_section({"synthetic": {}}) == [] and camera_pose_section({}) == []


def test_source_section_pairs_the_single_pass_with_the_headline():
    m = {"frames": 90, "mask_accuracy": 0.95, "type_accuracy": 1.0, "joint_median_cm": 20.0, "base_median_cm": 9.0}
    fit = {**m, "joint_median_cm": 12.5, "base_median_cm": 7.25}
    single = {s: {"all": m, "by_family": {"KUKA": m}} for s in ("synthetic", "recorded")}
    fitted = {s: {"all": fit, "by_family": {"KUKA": fit}} for s in ("synthetic", "recorded")}
    text = "\n".join(source_section(single, fitted, "fit"))
    assert "joint median cm, single / fit" in text
    assert "| recorded | KUKA | 90 | 95.0 / 95.0 | 100.0 / 100.0 | 20.00 / 12.50 | 9.00 / 7.25 |" in text
    plain = "\n".join(source_section(single))                       # no headline: single-pass figures only
    assert "| recorded | KUKA | 90 | 95.0 | 100.0 | 20.00 | 9.00 |" in plain and " / " not in plain


def test_camera_pose_section_shows_one_and_pooled_images_per_family():
    one = {"frames": 90, "images_pooled": 1, "rotation_median_deg": 3.0, "translation_median_cm": 4.0,
           "add_median_cm": 3.5, "add_auc_10cm": 0.6}
    ten = {"estimates": 9, "recordings": 1, "images_pooled": 10, "rotation_median_deg": 1.0,
           "translation_median_cm": 1.5, "add_median_cm": 1.2, "add_auc_10cm": 0.85}
    pose = {"source": "synthetic", "by_family": {"UR": one, "Panda": one},
            "tripod": {"images_pooled": 10, "by_family": {"Panda": {"images_1": one, "images_10": ten}},
                       "all": {"images_1": one, "images_10": ten}}}
    text = "\n".join(camera_pose_section(pose))
    assert "| UR | synthetic | rigid | 1 | 90 |" in text and "| Panda | tripod | rigid | 10 | 9 | 1.00 |" in text
    assert "| Panda | tripod | rigid | 1 | 90 | 3.00 |" in text and "rigid + rays" not in text.split("|---")[-1]
    both = "\n".join(camera_pose_section({**pose, "fit": "rays", "rigid": pose}))
    assert "| UR | synthetic | rigid + rays | 1 | 90 |" in both and "| UR | synthetic | rigid | 1 | 90 |" in both
    assert both.index("| rigid + rays |") < both.index("| synthetic | rigid |")     # the evaluated fit first


@pytest.mark.parametrize("n", [1, 4])
def test_fewer_frames_than_images_pool_them_all(n):
    src, T = _static_scene(n + 2, 3)
    exact = [(T[:3, :3] @ p.T).T + T[:3, 3] for p in src[:n]]
    e = pooled_errors(src[:n], exact, T, 10)
    assert len(e["add_m"]) == 1 and e["add_m"][0] < 1e-6
