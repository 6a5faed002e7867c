"""armpose.fit_sigmas: the fit's weights from a network's errors on held-out training frames."""
import numpy as np
import pytest
import torch

from armpose.data import split_indices
from armpose.fit_sigmas import held_out_rows, sigmas_from_predictions
from armpose.labels.dataset import load_dataset


def test_sigmas_are_the_median_ray_error_and_the_scaled_log_depth_error():
    rng = np.random.default_rng(0)
    n = 50
    truth = {"joints": np.column_stack([rng.uniform(-0.5, 0.5, (n * 7, 2)), rng.uniform(1.5, 2.5, n * 7)]).reshape(n, 7, 3),
             "base": np.tile([0.0, 0.2, 2.0], (n, 1)), "type": np.array([0] * 30 + [4] * 20),
             "joint_valid": np.ones((n, 7), bool)}
    truth["joint_valid"][:30, 6] = False                                   # a 6-joint type
    shift, scale = 0.01, 1.05                                              # every ray off by 0.01, every depth by 5 %
    pred = {"joints": truth["joints"] * scale + np.array([shift, 0.0, 0.0]) * truth["joints"][..., 2:] * scale,
            "base": truth["base"] * scale + np.array([shift, 0.0, 0.0]) * truth["base"][:, 2:] * scale,
            "type": truth["type"].copy()}
    out = sigmas_from_predictions(pred, truth, ["ur3", "ur5", "ur10", "iiwa", "panda"])
    assert set(out) == {"ur3", "panda"} and out["ur3"]["frames"] == 30
    assert out["ur3"]["ray_sigma"] == pytest.approx(0.01, abs=1e-5)
    assert out["ur3"]["log_depth_sigma"] == pytest.approx(np.log(1.05) * np.sqrt(7), abs=1e-4)   # base + 6 joints
    assert out["panda"]["log_depth_sigma"] == pytest.approx(np.log(1.05) * np.sqrt(8), abs=1e-4)
    assert out["ur3"]["depth_ratio"] == out["panda"]["depth_ratio"] == pytest.approx(1.05)
    pred["joints"][10:30] *= 0.9 / scale                                   # twenty UR3 frames typed as Panda, 10 % too close
    pred["type"][10:30] = 4
    out = sigmas_from_predictions(pred, truth, ["ur3", "ur5", "ur10", "iiwa", "panda"])
    assert out["ur3"]["depth_ratio"] == pytest.approx(1.05)                # over the frames typed as each type,
    assert out["panda"]["depth_ratio"] == pytest.approx((1.05 + 0.9) / 2)  # not the true type's (0.9 for UR3)
    pred["type"][:] = 4                                                    # no frame typed UR3: no ratio for it
    assert "depth_ratio" not in sigmas_from_predictions(pred, truth, ["ur3", "ur5", "ur10", "iiwa", "panda"])["ur3"]


def test_held_out_rows_are_training_rows_outside_the_used_ones(tiny_project):
    root, _ = tiny_project
    data = root / "data" / "labels"
    arrays, _ = load_dataset(data)
    train = split_indices(arrays, "train")
    used = train[::2]
    rows = held_out_rows(data, used, [0, 4], seed=1, per_type=3)
    assert len(np.intersect1d(rows, used)) == 0 and np.isin(rows, train).all()
    robot = np.asarray(arrays["robot"])[rows]
    assert set(robot.tolist()) <= {0, 4} and all((robot == t).sum() <= 3 for t in (0, 4))
    assert np.array_equal(rows, held_out_rows(data, used, [0, 4], seed=1, per_type=3))


def test_add_fit_sigmas_measures_held_out_frames_and_stores_them_once(tiny_project, tmp_path):
    from armpose.fit_sigmas import FIT_SIGMAS_VERSION, add_fit_sigmas, checkpoint_fit_sigmas
    from armpose.model import build_model
    from armpose.train import save_checkpoint
    root, tparams = tiny_project
    data = root / "data" / "labels"
    base = {**tparams["base"], "model": {"width": 8}}
    old_sigmas = {"ur3": {"ray_sigma": 1.0, "log_depth_sigma": 1.0, "frames": 1}}
    cfg = {"robots": ["ur3", "panda"], "augment": {"zoom": {"p": 0.5}}}
    ckpt = tmp_path / "model.pt"
    save_checkpoint(ckpt, build_model(base["model"]), None, None, 1, "transfer_stage2",
                    {"stage": "transfer_stage2", "cfg": cfg, "base": base})
    arrays, _ = load_dataset(data)
    used = split_indices(arrays, "train")[::2]
    sigmas = add_fit_sigmas(ckpt, data, used, seed=0)
    assert set(sigmas) == {"ur3", "panda"}                                # the stage's robots only
    assert all(v["ray_sigma"] > 0 and v["log_depth_sigma"] > 0 and v["frames"] > 0 for v in sigmas.values())
    assert checkpoint_fit_sigmas(ckpt) == sigmas
    stored = ckpt.read_bytes()
    assert add_fit_sigmas(ckpt, data, used, seed=0) == sigmas and ckpt.read_bytes() == stored
    old = torch.load(ckpt, weights_only=True)
    assert old["extra"]["fit_sigmas_version"] == FIT_SIGMAS_VERSION
    old["extra"]["fit_sigmas"] = old_sigmas                             # sigmas of an older version
    del old["extra"]["fit_sigmas_version"]
    torch.save(old, ckpt)
    assert add_fit_sigmas(ckpt, data, used, seed=0) == sigmas == checkpoint_fit_sigmas(ckpt)   # measured again


def test_add_fit_sigmas_on_mirror_measures_the_mirror_tests_zoom_estimates(tiny_project, tmp_path):
    from armpose.evaluate import predict_split
    from armpose.fit_sigmas import add_fit_sigmas, held_out_rows
    from armpose.model import build_model
    from armpose.train import load_checkpoint, save_checkpoint
    from armpose.zoom_test import settings_from_config
    root, tparams = tiny_project
    data = root / "data" / "labels"
    base = {**tparams["base"], "model": {"width": 8}}
    config = {"stage": "transfer_stage2", "cfg": {"robots": ["ur3", "panda"], "augment": {"zoom": {"p": 0.5}}},
              "base": base}
    torch.manual_seed(0)
    model = build_model(base["model"]).eval()
    for p in model.parameters():             # an untrained head predicts one depth: give it some spread
        p.data.add_(0.05 * torch.randn_like(p))
    ckpt = tmp_path / "model.pt"
    save_checkpoint(ckpt, model, None, None, 1, "transfer_stage2", config)
    arrays, _ = load_dataset(data)
    used = split_indices(arrays, "train")[::2]
    rows = held_out_rows(data, used, [0, 4], seed=0)
    types = list(base["robot_types"])

    def fit_sigmas_on_mirror(path):
        return load_checkpoint(path)["extra"]["fit_sigmas_on_mirror"]

    def expected(on_mirror):
        pred, truth = predict_split(model, data, rows=rows, mirror=on_mirror, zoom=True,
                                    zoom_settings=settings_from_config(config), zoom_on_mirror=on_mirror)
        return sigmas_from_predictions(pred["zoom"], truth, types)

    single = add_fit_sigmas(ckpt, data, used, seed=0)
    assert single == expected(False) and not fit_sigmas_on_mirror(ckpt)
    mirrored = add_fit_sigmas(ckpt, data, used, seed=0, on_mirror=True)   # other passes: measured again
    assert mirrored == expected(True) and fit_sigmas_on_mirror(ckpt)
    assert mirrored != single
    assert add_fit_sigmas(ckpt, data, used, seed=0, on_mirror=True) == mirrored
