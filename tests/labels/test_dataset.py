"""The labelled dataset of a tiny rendered project: joints on the mask, splits, determinism, resume."""
import json
import shutil

import numpy as np

from armpose.labels.dataset import ARRAYS, load_dataset, split_for
from armpose.labels.quality import joints_near_mask
from armpose.stages import labels


def test_projected_joints_lie_on_the_mask(tiny_project):
    root, _ = tiny_project
    arrays, index = load_dataset(root / "data" / "labels")
    assert index["num_frames"] == 60
    on_mask = joints_near_mask(arrays["masks"], arrays["joints"], arrays["joint_valid"], arrays["intrinsics"])
    assert on_mask.mean() >= 0.99
    assert index["joints_on_mask_fraction"] == on_mask.mean()


def test_joints_off_the_mask_are_detected():
    mask = np.zeros((1, 20, 20), np.uint8)
    mask[0, 5:10, 5:10] = 1
    joints = np.array([[[0.0, 0.0, 1.0], [0.5, 0.5, 1.0]]])  # projects to (7, 7) and (17, 17)
    valid = np.array([[True, True]])
    K = np.array([[10.0, 10.0, 7.0, 7.0]])
    assert not joints_near_mask(mask, joints, valid, K)[0]
    assert joints_near_mask(mask, joints, np.array([[True, False]]), K)[0]


def test_dataset_shapes_and_classes(tiny_project):
    root, params = tiny_project
    arrays, index = load_dataset(root / "data" / "labels")
    n = index["num_frames"]
    assert arrays["images"].shape == (n, 212, 256, 3) and arrays["images"].dtype == np.uint8
    assert arrays["masks"].shape == (n, 212, 256) and set(np.unique(arrays["masks"])) <= {0, 1}
    assert arrays["joints"].shape == (n, 7, 3)
    counts = np.bincount(arrays["robot"], minlength=5)
    assert counts.tolist() == [12] * 5
    assert (arrays["joint_valid"].sum(1) == np.where(arrays["robot"] < 3, 6, 7)).all()
    assert (arrays["base"][:, 2] > 0).all(), "robot base behind the camera"
    assert index["num_train"] + index["num_test"] == n


def test_synthetic_split_is_per_frame_and_reproducible():
    synthetic = split_for("data/render/ur5/ur5_000", 2000, 2019, 0.2)
    assert 0.15 < synthetic.mean() < 0.25
    np.testing.assert_array_equal(synthetic, split_for("data/render/ur5/ur5_000", 2000, 2019, 0.2))
    assert not np.array_equal(synthetic, split_for("data/render/ur5/ur5_001", 2000, 2019, 0.2))


def test_same_recordings_give_byte_identical_labels(tiny_project, tmp_path):
    root, params = tiny_project
    shutil.copytree(root / "data" / "render", tmp_path / "data" / "render")
    labels.run(params, tmp_path)
    for name in ARRAYS:
        a = (root / "data" / "labels" / f"{name}.npy").read_bytes()
        b = (tmp_path / "data" / "labels" / f"{name}.npy").read_bytes()
        assert a == b, name


def test_labels_resume_from_the_cache(tiny_project, tmp_path, monkeypatch):
    root, params = tiny_project
    shutil.copytree(root / "data", tmp_path / "data")
    calls = []
    import armpose.stages.labels as stage
    real = stage.label_recording
    monkeypatch.setattr(stage, "label_recording", lambda *a, **k: calls.append(a) or real(*a, **k))
    p = json.loads(json.dumps(params))
    p["base"]["num_workers"] = 1
    labels.run(p, tmp_path)
    assert calls == [], "unchanged recordings were labelled again"
