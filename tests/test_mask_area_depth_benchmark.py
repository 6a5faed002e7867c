"""benchmarks/mask_area_depth.py: per-frame mask-area and depth ratios, and their summary."""
import importlib.util
import sys
from pathlib import Path

import numpy as np

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def _benchmark():
    sys.path.insert(0, str(BENCH))          # the script imports its neighbour checkpoint_cli
    try:
        spec = importlib.util.spec_from_file_location("mask_area_depth", BENCH / "mask_area_depth.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module
    finally:
        sys.path.remove(str(BENCH))


def test_a_mask_grown_into_the_scene_and_a_robot_placed_closer_correlate_negatively():
    bench = _benchmark()
    n, h, w = 6, 20, 30
    truth = np.zeros((n, h, w), bool)
    truth[:, 5:15, 10:20] = True                                     # 100 px each
    pred = truth.copy()
    for i in range(n):
        pred[i, 15:15 + i, 10:20] = True                             # 10 i px more, all false positives
    pred[0, 5, 10] = False                                           # one missed pixel
    true_joints = np.tile([[0.1, 0.0, 2.0], [0.2, 0.1, 2.2]], (n, 1, 1))
    scale = 1 / (1 + 0.1 * np.arange(n))                             # the larger the mask, the closer
    pred_joints = true_joints * scale[:, None, None]
    valid = np.ones((n, 2), bool)
    r = bench.frame_ratios(pred, truth, pred_joints, true_joints, valid)
    assert np.allclose(r["area_ratio"], (100 + 10 * np.arange(n) - (np.arange(n) == 0)) / 100)
    assert np.allclose(r["false_positive_ratio"], 0.1 * np.arange(n))
    assert np.allclose(r["depth_ratio"], scale)
    err = np.linalg.norm(pred_joints - true_joints, axis=-1)
    s = bench.group_summary(r, err, valid, np.ones(n, bool))
    assert s["frames"] == n and s["corr_log_area_log_depth"] < -0.99
    assert s["joint_median_cm"] == round(100 * float(np.median(err)), 2)
    empty = bench.frame_ratios(np.zeros((1, h, w), bool), np.zeros((1, h, w), bool), pred_joints[:1],
                               true_joints[:1], valid[:1])
    assert np.isnan(empty["area_ratio"][0]) and np.isnan(empty["false_positive_ratio"][0])
    assert bench.group_summary(r, err, valid, np.arange(n) < 2)["corr_log_area_log_depth"] is None
