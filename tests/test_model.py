"""The multi-objective CNN: output contract, layer groups and freezing for transfer learning."""
import math

import pytest
import torch
from torch import nn

from armpose.losses import multi_objective_loss
from armpose.model import (GROUPS, ArmPoseNet, build_model, count_parameters, group_modules, predicted_mask,
                           group_parameters, set_trainable)

H, W = 48, 64  # small images keep the tests fast; the model works at any size


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def tiny_batch(b: int = 4, h: int = H, w: int = W, seed: int = 0) -> dict:
    g = torch.Generator().manual_seed(seed)
    valid = torch.ones(b, 7, dtype=torch.bool)
    valid[0, 6] = False
    return {"image": torch.rand(b, 3, h, w, generator=g),
            "mask": (torch.rand(b, h, w, generator=g) < 0.2).to(torch.uint8),
            "joints": torch.randn(b, 7, 3, generator=g) * 0.3 + torch.tensor([0.0, 0.0, 2.5]),
            "joint_valid": valid,
            "base": torch.randn(b, 3, generator=g) * 0.3 + torch.tensor([0.0, 0.3, 2.5]),
            "robot": torch.arange(b) % 5}


def tiny_model(seed: int = 0) -> ArmPoseNet:
    torch.manual_seed(seed)
    return ArmPoseNet(width=8)


def test_output_shapes_and_dtypes_at_input_size():
    model = ArmPoseNet().eval()
    with torch.inference_mode():
        out = model(torch.rand(2, 3, 212, 256))
    assert out["mask_logits"].shape == (2, 1, 212, 256)
    assert out["joints"].shape == (2, 7, 3)
    assert out["base"].shape == (2, 3)
    assert out["type_logits"].shape == (2, 5)
    for v in out.values():
        assert v.dtype == torch.float32 and torch.isfinite(v).all()


def test_channels_last_gives_the_same_outputs():
    model = tiny_model().eval()
    x = torch.rand(2, 3, H, W)
    with torch.inference_mode():
        ref = model(x)
        out = model.to(memory_format=torch.channels_last)(x.contiguous(memory_format=torch.channels_last))
    for k in ref:
        torch.testing.assert_close(out[k], ref[k], rtol=1e-4, atol=1e-5)


def test_untrained_points_sit_at_the_depth_prior_in_front_of_the_camera():
    model = tiny_model().eval()
    with torch.inference_mode():
        out = model(torch.rand(2, 3, H, W))
    torch.testing.assert_close(out["joints"][..., 2], torch.full((2, 7), 2.5))
    torch.testing.assert_close(out["base"][:, 2], torch.full((2,), 2.5))
    assert (out["joints"][..., :2].abs() < 2.5 * 0.42).all()  # inside the field of view


def test_build_model_reads_config():
    model = build_model({"width": 8, "max_joints": 6, "num_types": 3})
    with torch.inference_mode():
        out = model.eval()(torch.rand(1, 3, H, W))
    assert out["joints"].shape == (1, 6, 3) and out["type_logits"].shape == (1, 3)
    assert count_parameters(build_model({})) == count_parameters(ArmPoseNet())
    with pytest.raises(ValueError, match="widht"):
        build_model({"widht": 8})


def test_groups_partition_the_parameters():
    model = tiny_model()
    ids = [id(p) for g in GROUPS for p in group_parameters(model, g)]
    assert len(ids) == len(set(ids))
    assert set(ids) == {id(p) for p in model.parameters()}
    assert sum(count_parameters(model, g) for g in GROUPS) == count_parameters(model)
    assert isinstance(group_modules(model, "heads.joints"), nn.Module)
    assert set(map(id, group_parameters(model, "heads.joints"))) < set(map(id, group_parameters(model, "heads")))
    with pytest.raises(KeyError):
        group_parameters(model, "trunk")
    with pytest.raises(KeyError):
        group_parameters(model, "decoder")


def test_gradients_reach_every_group():
    model = tiny_model().train()
    batch = tiny_batch()
    multi_objective_loss(model(batch["image"]), batch, {})["total"].backward()
    for name, p in model.named_parameters():
        assert p.grad is not None, name
    for g in GROUPS:
        assert sum(float(p.grad.abs().sum()) for p in group_parameters(model, g)) > 0, g


def _state(model: nn.Module) -> dict[str, torch.Tensor]:
    return {k: v.detach().clone() for k, v in model.state_dict().items()}


@pytest.mark.parametrize("trainable", [["heads"], ["trunk.late", "heads"], ["mask_decoder", "heads.base"]])
def test_set_trainable_freezes_exactly_the_other_groups(trainable):
    model = tiny_model()
    set_trainable(model, trainable)
    trained = {n for g in trainable for n, _ in group_modules(model, g).named_parameters(prefix=g)}
    assert {n for n, p in model.named_parameters() if p.requires_grad} == trained

    before = _state(model)
    # the optimizer sees every parameter, with weight decay: frozen ones must still not move
    opt = torch.optim.AdamW(model.parameters(), lr=1e-2, weight_decay=0.1)
    for step in range(3):
        model.train()
        batch = tiny_batch(seed=step)
        opt.zero_grad(set_to_none=True)
        multi_objective_loss(model(batch["image"]), batch, {})["total"].backward()
        opt.step()
    after = _state(model)

    def in_trained(key: str) -> bool:
        return any(key == g or key.startswith(g + ".") for g in trainable)
    for k in before:  # parameters and BatchNorm buffers alike
        if not in_trained(k):
            assert torch.equal(before[k], after[k]), f"frozen {k} changed"
    changed = [k for k in before if in_trained(k) and not torch.equal(before[k], after[k])]
    assert any(k.endswith("running_mean") for k in changed), "trainable BatchNorm statistics did not update"
    assert any(k.endswith("weight") for k in changed), "trainable weights did not update"


def test_frozen_batchnorm_stays_in_eval_mode_after_train():
    model = tiny_model()
    set_trainable(model, ["heads"])
    model.train()
    for name, m in model.named_modules():
        if isinstance(m, nn.BatchNorm2d):
            assert m.training == name.startswith("heads."), name
    set_trainable(model, list(GROUPS))
    model.train()
    assert all(m.training for m in model.modules())
    model.eval()
    assert not any(m.training for m in model.modules())


def test_mask_decision_uses_the_training_prior_threshold():
    model = build_model({"width": 4})
    logits = torch.tensor([-1.0, 0.5, 2.0, 3.5])
    assert predicted_mask(model, logits).tolist() == [False, True, True, True], "threshold 0 before any prior"
    model.set_mask_prior(0.05)          # log(0.95 / 0.05) = 2.944
    assert torch.isclose(model.mask_threshold, torch.tensor(math.log(19.0)))
    assert predicted_mask(model, logits).tolist() == [False, False, False, True]
    restored = build_model({"width": 4})
    restored.load_state_dict(model.state_dict())
    assert torch.equal(restored.mask_threshold, model.mask_threshold), "the threshold travels in the checkpoint"


def test_lifting_model_puts_joints_at_base_plus_offsets_and_trains_every_parameter():
    torch.manual_seed(0)
    model = build_model({"width": 8, "lift": True}).train()
    batch = tiny_batch()
    out = model(batch["image"])
    assert out["joint_offsets"].shape == (4, 7, 3) and out["base_direct"].shape == (4, 3)
    assert out["point_weights"].shape == (4, 8) and ((out["point_weights"] > 0) & (out["point_weights"] < 1)).all()
    torch.testing.assert_close(out["joints"], out["base"][:, None] + out["joint_offsets"])
    losses = multi_objective_loss(out, batch, {"offsets": 1.2, "direct": 0.3})
    assert {"offsets", "direct"} <= set(losses)
    losses["total"].backward()
    assert [n for n, p in model.named_parameters() if p.grad is None] == []   # DDP needs every one used
    with pytest.raises(ValueError, match="lift"):
        multi_objective_loss(tiny_model()(batch["image"]), batch, {"offsets": 1.0})


def test_lifting_model_config_round_trips_and_differs_from_the_direct_one():
    lifted = build_model({"width": 8, "lift": True, "lift_prior": 0.1})
    assert lifted.config["lift"] is True and lifted.config["lift_prior"] == 0.1
    assert build_model(lifted.config).config == lifted.config
    direct = tiny_model()
    assert direct.config["lift"] is False
    with pytest.raises(RuntimeError):
        direct.load_state_dict(lifted.state_dict())       # a checkpoint says which head it has


def test_heads_stay_float32_under_a_bfloat16_autocast():
    model = tiny_model().eval()
    x = torch.rand(2, 3, H, W)
    with torch.inference_mode():
        ref = model(x)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            out = model(x)
    for k in ("joints", "base", "type_logits"):
        assert out[k].dtype == torch.float32, k
        torch.testing.assert_close(out[k], ref[k], rtol=0.1, atol=0.05)   # only the trunk ran in bfloat16


def test_stride4_keypoint_heads_read_c1_and_give_finer_attention_maps():
    torch.manual_seed(0)
    fine, coarse = build_model({"width": 8, "keypoint_stride": 4}).eval(), tiny_model().eval()
    x = torch.rand(2, 3, H, W)
    with torch.inference_mode():
        out_fine, out_coarse = fine(x), coarse(x)
        feats = fine.trunk_features(x)
        from_cache = fine(features=feats)
    assert out_fine["joints_attention"].shape[-2:] == (H // 4, W // 4)
    assert out_coarse["joints_attention"].shape[-2:] == (H // 8, W // 8)
    assert len(feats) == 4 and len(coarse.trunk_features(x)) == 3
    torch.testing.assert_close(from_cache["joints"], out_fine["joints"])
    assert fine.config["keypoint_stride"] == 4 and build_model(fine.config).config == fine.config
    with pytest.raises(ValueError, match="c1"):
        fine(features=feats[1:])
    with pytest.raises(ValueError, match="keypoint_stride"):
        build_model({"width": 8, "keypoint_stride": 2})


def test_stride8_checkpoints_keep_their_parameter_names():
    names = set(tiny_model().state_dict())
    assert not any(".neck.fine." in n for n in names)
    assert {n for n in build_model({"width": 8, "keypoint_stride": 4}).state_dict()} - names == {
        n for n in build_model({"width": 8, "keypoint_stride": 4}).state_dict() if ".neck.fine." in n}


def test_skeleton_context_feeds_every_joints_image_position_to_each_depth():
    torch.manual_seed(0)
    model = build_model({"width": 8, "skeleton_context": True})
    assert model.heads.joints.mlp[0].weight.shape[1] == model.heads.joints.mlp[0].weight.shape[2] * 2 + 2 + 14
    assert build_model(model.config).config == model.config and model.config["skeleton_context"]
    batch = tiny_batch()
    out = model.train()(batch["image"])
    multi_objective_loss(out, batch, {})["total"].backward()
    for name, p in model.named_parameters():
        assert p.grad is not None, name
    # the last MLP layer starts at zero: an untrained head still sits at the depth prior
    with torch.inference_mode():
        fresh = build_model({"width": 8, "skeleton_context": True}).eval()(batch["image"])
    torch.testing.assert_close(fresh["joints"][..., 2], torch.full((4, 7), 2.5))
