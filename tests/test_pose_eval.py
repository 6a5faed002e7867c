"""Single-image camera-to-robot pose on labelled frames: exact with true points, worse with noise."""
import numpy as np

from armpose.labels.dataset import load_dataset
from armpose.pose_eval import frame_pose_errors, summarise_poses


def test_true_points_give_the_recorded_camera_pose_and_noise_degrades_it(tiny_project):
    root, _ = tiny_project
    arrays, index = load_dataset(root / "data" / "labels")
    rows = np.arange(len(arrays["split"]))
    truth = {"row": rows}
    exact = {"joints": np.asarray(arrays["joints"], np.float64), "base": np.asarray(arrays["base"], np.float64)}
    s = summarise_poses(frame_pose_errors(exact, truth, index, arrays, root), rows)
    assert s["frames"] == len(rows)
    assert s["rotation_median_deg"] < 0.01 and s["translation_median_cm"] < 0.01 and s["add_auc_10cm"] > 0.999
    rng = np.random.default_rng(0)
    noisy = {k: v + rng.normal(0, 0.03, v.shape) for k, v in exact.items()}
    n = summarise_poses(frame_pose_errors(noisy, truth, index, arrays, root), rows)
    assert n["translation_median_cm"] > 0.5 and n["add_auc_10cm"] < s["add_auc_10cm"]
