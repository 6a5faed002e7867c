"""Progressive resizing: settings checked, batches shrunk with labels that still project
right, and a pretraining run whose first steps are small."""
import numpy as np
import pytest
import torch

from armpose.config import profile_params
import armpose.train
from armpose.resolution import check_low_res, check_stage_low_res, downscale_batch, input_scale
from armpose.stages import pretrain
from armpose.train import load_checkpoint


def _project(points: torch.Tensor, intrinsics: torch.Tensor) -> torch.Tensor:
    fx, fy, cx, cy = intrinsics.unbind(-1)
    return torch.stack([fx[:, None] * points[..., 0] / points[..., 2] + cx[:, None],
                        fy[:, None] * points[..., 1] / points[..., 2] + cy[:, None]], -1)


def _batch(h: int = 212, w: int = 256) -> dict:
    """Two frames whose mask is a filled box around a 3D point's projection."""
    intrinsics = torch.tensor([[309.2, 309.2, 127.5, 105.5], [250.0, 260.0, 120.0, 100.0]])
    points = torch.tensor([[[0.2, -0.1, 2.0]], [[-0.3, 0.25, 1.5]]])
    uv = _project(points, intrinsics)
    mask = torch.zeros(2, h, w)
    for i, (u, v) in enumerate(uv[:, 0].round().long().tolist()):
        mask[i, v - 20:v + 20, u - 30:u + 30] = 1
    return {"image": torch.rand(2, 3, h, w), "mask": mask, "joints": points, "base": points[:, 0],
            "intrinsics": intrinsics, "image_size": torch.tensor([[w, h], [w, h]]), "robot": torch.tensor([0, 1])}


def test_settings_are_checked_with_the_bad_value_named():
    assert check_low_res(None) is None and check_low_res({}) is None
    assert check_low_res({"scale": 0.5, "steps": 10}) == {"scale": 0.5, "steps": 10}
    for bad, named in [({"scale": 1.5, "steps": 10}, "1.5"), ({"scale": 0.5, "steps": -1}, "-1"),
                       ({"scale": 0.5, "steps": 2.5}, "2.5"), ({"scale": 0.5}, r"\{'scale': 0\.5\}"),
                       ([0.5, 10], r"\[0\.5, 10\]")]:
        with pytest.raises(ValueError, match=named):
            check_low_res(bad)


def test_input_scale_follows_the_step_number():
    low = {"scale": 0.5, "steps": 3}
    assert [input_scale(low, s) for s in range(5)] == [0.5, 0.5, 0.5, 1.0, 1.0]
    assert input_scale(None, 0) == 1.0


def test_downscaled_labels_still_project_onto_the_downscaled_pixels():
    batch = _batch()
    small = downscale_batch(batch, 0.5)
    assert small["image"].shape == (2, 3, 106, 128) and small["mask"].shape == (2, 106, 128)
    assert small["image_size"].tolist() == [[128, 106], [128, 106]]
    assert torch.equal(small["joints"], batch["joints"]) and torch.equal(small["robot"], batch["robot"])
    uv, uv_small = _project(batch["joints"], batch["intrinsics"]), _project(small["joints"], small["intrinsics"])
    # pixel centres: u' + 0.5 = (u + 0.5) * w' / w
    assert torch.allclose(uv_small + 0.5, (uv + 0.5) * torch.tensor([128 / 256, 106 / 212]), atol=1e-4)
    # the box mask keeps its place and a quarter of its area
    for i in range(2):
        v, u = np.argwhere(small["mask"][i].numpy() > 0).mean(0)
        assert abs(u - float(uv_small[i, 0, 0])) < 1.0 and abs(v - float(uv_small[i, 0, 1])) < 1.0
        assert abs(float(small["mask"][i].sum()) - float(batch["mask"][i].sum()) / 4) <= 40
    assert downscale_batch(batch, 1.0) is batch


def test_area_averaging_keeps_pixel_centres_where_the_intrinsics_say():
    """The intensity centroid of a small bright box, a quantity area averaging preserves
    exactly, maps as ``u' + 0.5 = (u + 0.5) * s``: a wrong half-pixel convention is 0.25 px off."""
    batch = _batch()
    image = torch.zeros(2, 3, 212, 256)
    image[:, :, 100:104, 60:66] = 1.0          # rows 100-103, columns 60-65: centroid (62.5, 101.5)
    batch["image"] = image
    small = downscale_batch(batch, 0.5)["image"][0, 0].numpy()
    v, u = np.indices(small.shape)
    uc, vc = (u * small).sum() / small.sum(), (v * small).sum() / small.sum()
    assert abs(uc - ((62.5 + 0.5) * 0.5 - 0.5)) < 1e-3 and abs(vc - ((101.5 + 0.5) * 0.5 - 0.5)) < 1e-3


def test_pretraining_shrinks_exactly_its_first_steps(tiny_project, tmp_path, monkeypatch):
    root, tparams = tiny_project
    (tmp_path / "data").symlink_to(root / "data")
    params = profile_params("quick")
    params["base"] = tparams["base"]
    params["pretrain"].update(max_steps=4, eval_every=4, low_res={"scale": 0.5, "steps": 2})
    seen = []

    def spy(batch, scale):
        out = downscale_batch(batch, scale)
        seen.append((scale, tuple(out["image"].shape[-2:])))
        return out

    monkeypatch.setattr(armpose.train, "downscale_batch", spy)
    pretrain.run(params, tmp_path)
    h, w = params["base"]["input_size"]["height"], params["base"]["input_size"]["width"]
    assert seen == [(0.5, (round(h / 2), round(w / 2)))] * 2 + [(1.0, (h, w))] * 2
    ckpt = load_checkpoint(tmp_path / "models" / "pretrain" / "model.pt")
    assert ckpt["step"] == 4 and ckpt["config"]["cfg"]["low_res"] == {"scale": 0.5, "steps": 2}
    assert all(torch.isfinite(v).all() for v in ckpt["model"].values() if v.is_floating_point())


def test_low_res_is_refused_with_a_plateau_rule_or_a_teacher():
    low = {"scale": 0.5, "steps": 3}
    with pytest.raises(ValueError, match=r"plateau \{'delta': 0\.01"):
        check_stage_low_res("train_full", {"low_res": low, "plateau": {"delta": 0.01, "patience": 5}}, False)
    with pytest.raises(ValueError, match="distill .*teacher.pt"):
        check_stage_low_res("pretrain", {"low_res": low, "distill": {"teacher": "teacher.pt"}}, False)
    assert check_stage_low_res("pretrain", {"low_res": low, "plateau": None, "distill": None}, False) == low
    assert check_stage_low_res("pretrain", {"low_res": {"scale": 0.5, "steps": 0}}, True) == {"scale": 0.5, "steps": 0}


def test_low_res_is_refused_on_cached_trunk_features(tiny_project, tmp_path):
    root, tparams = tiny_project
    (tmp_path / "data").symlink_to(root / "data")
    params = profile_params("quick")
    params["base"] = tparams["base"]
    params["pretrain"].update(max_steps=2, eval_every=2)
    pretrain.run(params, tmp_path)
    params["transfer_stage1"].update(max_steps=2, low_res={"scale": 0.5, "steps": 1}, distill=None, plateau=None)
    from armpose.stages import transfer_stage1
    with pytest.raises(ValueError, match="cached trunk features"):
        transfer_stage1.run(params, tmp_path)
