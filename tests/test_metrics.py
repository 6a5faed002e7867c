"""Metrics on hand-made predictions whose answers are known."""
import numpy as np
import pytest

from armpose.metrics import (confusion_matrix, depth_breakdown, error_by_distance, frame_depth_ratio, mask_counts,
                             summarise)


def _case():
    n, j = 4, 7
    truth_joints = np.zeros((n, j, 3))
    truth_joints[..., 2] = 2.0
    valid = np.ones((n, j), bool)
    valid[:2, 6] = False                                     # two 6-joint robots
    pred_joints = truth_joints.copy()
    pred_joints[..., 0] += np.array([0.01, 0.02, 0.03, 0.20])[:, None]   # x errors in metres
    truth = {"joints": truth_joints, "joint_valid": valid, "base": np.zeros((n, 3)),
             "type": np.array([0, 0, 1, 2]), "intrinsics": np.tile([100.0, 100.0, 50.0, 50.0], (n, 1))}
    pm = np.zeros((n, 10, 10), bool)
    tm = np.zeros((n, 10, 10), bool)
    tm[:, :5, :4] = True                                     # 20 robot pixels
    pm[:, :5, :2] = True                                     # 10 of them found, no false positive
    pred = {"joints": pred_joints, "base": np.full((n, 3), 0.05), "type": np.array([0, 1, 1, 2]),
            "mask_counts": mask_counts(pm, tm)}
    return pred, truth


def test_summary_values_match_hand_computation():
    pred, truth = _case()
    m = summarise(pred, truth, np.arange(4))
    assert m["mask_accuracy"] == pytest.approx(0.9)          # 10 wrong pixels of 100
    assert m["mask_iou"] == pytest.approx(0.5)
    assert m["type_accuracy"] == pytest.approx(0.75)
    assert m["joint_median_cm"] == pytest.approx(3.0)        # errors 1 (x6), 2 (x6), 3 (x7), 20 (x7) cm
    assert m["base_median_cm"] == pytest.approx(100 * np.sqrt(3) * 0.05)
    # ADD per frame 0.01, 0.02, 0.03, 0.2 -> AUC = mean(1 - add/0.1 clipped) = (0.9 + 0.8 + 0.7 + 0) / 4
    assert m["add_auc_10cm"] == pytest.approx(0.6, abs=1e-6)
    # projected x error = fx * dx / z = 100 * dx / 2 -> 0.5, 1, 1.5, 10 px
    assert m["pck_5px"] == pytest.approx(19 / 26)
    assert m["pck_10px"] == pytest.approx(19 / 26)
    assert len(m["per_joint_median_cm"]) == 7


def test_pck_divides_network_pixels_by_the_pixel_scale_per_frame():
    """Network-input errors 0.5, 1, 1.5, 10 px; a frame's scale of 0.25 network pixels per PCK
    pixel makes its error 4x larger in PCK pixels (a recording from a finer camera)."""
    pred, truth = _case()
    assert summarise(pred, truth, np.arange(4), 0.25)["pck_5px"] == pytest.approx(12 / 26)  # 2, 4, 6, 40 px
    per_frame = np.array([1.0, 1.0, 0.25, 1.0])                                          # 0.5, 1, 6, 10 px
    m = summarise(pred, truth, np.arange(4), per_frame)
    assert m["pck_5px"] == pytest.approx(12 / 26) and m["pck_10px"] == pytest.approx(19 / 26)
    assert summarise(pred, truth, np.array([2, 3]), per_frame)["pck_10px"] == pytest.approx(7 / 14)


def test_depth_breakdown_separates_ray_errors_from_depth_errors():
    truth = np.zeros((2, 3, 3))
    truth[..., 0] = [0.1, 0.2, 0.3]
    truth[..., 2] = 2.0
    valid = np.ones((2, 3), bool)
    scaled = truth * np.array([1.10, 0.95])[:, None, None]       # right rays, depth off by 10 % and 5 %
    m = depth_breakdown(scaled, truth, valid)
    assert m["joint_median_true_depth_cm"] == pytest.approx(0.0, abs=1e-9)
    assert m["frame_depth_error_median_pct"] == pytest.approx(7.5)  # median of 10 and 5
    assert m["depth_error_median_pct"] == pytest.approx(7.5)
    assert m["joint_median_true_frame_scale_cm"] == pytest.approx(0.0, abs=1e-9)   # a pure scale error
    ratios = np.array([1.0, 1.1, 1.2])             # each joint on its own ray, at its own depth error
    bent = truth * ratios[None, :, None]
    m = depth_breakdown(bent, truth, valid)
    assert m["joint_median_true_depth_cm"] == pytest.approx(0.0, abs=1e-9)
    assert m["frame_depth_error_median_pct"] == pytest.approx(10.0)   # the shared part: the median ratio
    left = np.linalg.norm(truth, axis=-1) * np.abs(ratios / 1.1 - 1)  # what scaling by 1 / 1.1 leaves
    assert m["joint_median_true_frame_scale_cm"] == pytest.approx(100 * np.median(left))
    assert m["joint_median_true_frame_scale_cm"] > 5
    sideways = truth.copy()
    sideways[..., 0] += 0.04                                     # right depth, 4 cm sideways
    sideways[1, 2, 0] = np.nan                                   # an invalid slot's garbage
    valid[1, 2] = False
    m = depth_breakdown(sideways, truth, valid)
    assert m["joint_median_true_depth_cm"] == pytest.approx(4.0)
    assert m["depth_error_median_pct"] == pytest.approx(0.0) and m["frame_depth_error_median_pct"] == pytest.approx(0.0)


def test_empty_selection_gives_nan_not_an_error():
    pred, truth = _case()
    m = summarise(pred, truth, np.array([], np.int64))
    assert m["frames"] == 0 and np.isnan(m["joint_median_cm"])


def test_confusion_matrix_rows_are_the_truth():
    m = confusion_matrix(np.array([0, 1, 1, 2]), np.array([0, 0, 1, 2]), 3)
    assert m.tolist() == [[1, 1, 0], [0, 1, 0], [0, 0, 1]]


def test_error_by_distance_bins():
    err = np.array([[0.01, np.nan], [0.05, 0.07], [0.2, 0.2]])
    rows = error_by_distance(err, np.array([1.1, 1.9, 3.0]), np.array([1.0, 2.0, 4.0]))
    assert rows[0]["frames"] == 2 and rows[0]["joint_median_cm"] == pytest.approx(5.0)
    assert rows[1]["joint_median_cm"] == pytest.approx(20.0)


def test_frame_depth_ratio_is_the_median_over_valid_joints_and_nan_without_one():
    truth = np.array([[[0.1, 0.0, 2.0], [0.0, 0.2, 2.5], [0.3, 0.1, 3.0]]] * 2)
    pred = truth.copy()
    pred[0, :, 2] *= [1.1, 1.2, 9.0]            # the invalid third joint must not count
    valid = np.array([[True, True, False], [False, False, False]])
    ratio = frame_depth_ratio(pred, truth, valid)
    assert np.isclose(ratio[0], 1.15) and np.isnan(ratio[1])
