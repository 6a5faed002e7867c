"""Losses (paper eq. 1-8) against hand-computed values."""
import math

import pytest
import torch
import torch.nn.functional as F

from armpose.losses import (PAPER_WEIGHTS, base_loss, joints_loss, mask_loss, multi_objective_loss,
                            type_loss)
from armpose.model import ArmPoseNet


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def softplus(z: float) -> float:
    return math.log1p(math.exp(z))


def test_mask_loss_2x2_by_hand():
    # one foreground pixel of four: P(fg) = 1/4, w_fg = 4, w_bg = 4/3
    mask = torch.tensor([[[1, 0], [0, 0]]], dtype=torch.uint8)
    logits = torch.tensor([[[[0.0, 1.0], [-1.0, 2.0]]]])
    # -log(sigmoid(z)) = softplus(-z) for foreground, -log(1 - sigmoid(z)) = softplus(z) for background
    expected = (4 * softplus(0.0) + 4 / 3 * (softplus(1.0) + softplus(-1.0) + softplus(2.0))) / 4
    assert mask_loss(logits, mask).item() == pytest.approx(expected, rel=1e-6)
    assert mask_loss(logits, mask.float()).item() == pytest.approx(expected, rel=1e-6)
    assert mask_loss(logits[:, 0], mask).item() == pytest.approx(expected, rel=1e-6)


def test_mask_loss_is_the_batch_mean_and_balances_classes():
    mask = torch.tensor([[[1, 0], [0, 0]], [[1, 1], [1, 0]]], dtype=torch.uint8)
    logits = torch.randn(2, 1, 2, 2)
    each = [mask_loss(logits[i:i + 1], mask[i:i + 1]) for i in range(2)]
    assert mask_loss(logits, mask).item() == pytest.approx((each[0] + each[1]).item() / 2, rel=1e-6)
    # balanced: an all-zero prediction costs log 2 per class, whatever the foreground share
    for m in mask:
        assert mask_loss(torch.zeros(1, 1, 2, 2), m[None]).item() == pytest.approx(2 * math.log(2), rel=1e-6)


def test_mask_loss_all_background_is_finite():
    mask = torch.zeros(1, 4, 4)
    loss = mask_loss(torch.zeros(1, 1, 4, 4), mask)
    # P(fg) clamps to 1/N: w_bg = 1 / (1 - 1/16)
    assert loss.item() == pytest.approx(math.log(2) * 16 / 15, rel=1e-6)


def test_joints_loss_mean_distance_over_valid_joints():
    gt = torch.zeros(2, 7, 3)
    pred = torch.zeros(2, 7, 3)
    pred[0, 0] = torch.tensor([3.0, 4.0, 0.0])   # 5
    pred[0, 1] = torch.tensor([0.0, 0.0, 1.0])   # 1, others 0: image 0 = 6 / 6 valid
    pred[1, 2] = torch.tensor([0.0, 2.0, 0.0])   # 2: image 1 = 2 / 7 valid
    valid = torch.ones(2, 7, dtype=torch.bool)
    valid[0, 6] = False
    pred[0, 6] = torch.tensor([100.0, 0.0, 0.0])
    expected = (6 / 6 + 2 / 7) / 2
    assert joints_loss(pred, gt, valid).item() == pytest.approx(expected, rel=1e-6)
    # the invalid slot is ignored: another prediction, or a NaN label there, changes nothing
    pred2 = pred.clone().requires_grad_(True)
    with torch.no_grad():
        pred2[0, 6] = torch.tensor([-7.0, 3.0, 1.0])
    gt_nan = gt.clone()
    gt_nan[0, 6] = float("nan")
    loss = joints_loss(pred2, gt_nan, valid)
    assert loss.item() == pytest.approx(expected, rel=1e-6)
    loss.backward()
    assert torch.isfinite(pred2.grad).all() and (pred2.grad[0, 6] == 0).all()


def test_joints_loss_skips_images_without_valid_joints():
    pred, gt = torch.ones(2, 7, 3), torch.zeros(2, 7, 3)
    valid = torch.zeros(2, 7, dtype=torch.bool)
    valid[1, :6] = True
    assert joints_loss(pred, gt, valid).item() == pytest.approx(math.sqrt(3), rel=1e-6)


def test_base_loss_is_the_euclidean_distance():
    pred = torch.tensor([[3.0, 4.0, 2.5], [0.0, 0.0, 1.0]])
    gt = torch.tensor([[0.0, 0.0, 2.5], [0.0, 0.0, 3.0]])
    assert base_loss(pred, gt).item() == pytest.approx((5 + 2) / 2)


def test_type_loss_is_cross_entropy():
    assert type_loss(torch.zeros(3, 5), torch.tensor([0, 2, 4])).item() == pytest.approx(math.log(5), rel=1e-6)
    logits = torch.tensor([[2.0, 0.0, 0.0, 0.0, 0.0]])
    expected = -math.log(math.exp(2) / (math.exp(2) + 4))
    assert type_loss(logits, torch.tensor([0])).item() == pytest.approx(expected, rel=1e-6)


def random_case(b: int = 3, h: int = 6, w: int = 8, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    out = {"mask_logits": torch.randn(b, 1, h, w, generator=g), "joints": torch.randn(b, 7, 3, generator=g),
           "base": torch.randn(b, 3, generator=g), "type_logits": torch.randn(b, 5, generator=g)}
    valid = torch.ones(b, 7, dtype=torch.bool)
    valid[:, 6] = False
    batch = {"image": torch.rand(b, 3, h, w, generator=g),
             "mask": (torch.rand(b, h, w, generator=g) < 0.3).float(),
             "joints": torch.randn(b, 7, 3, generator=g), "joint_valid": valid,
             "base": torch.randn(b, 3, generator=g), "robot": torch.tensor([0, 1, 4])[:b]}
    return out, batch


@pytest.mark.parametrize("weights", [PAPER_WEIGHTS, {"mask": 2.0, "joints": 0.5, "base": 0.0, "type": 3.0}])
def test_total_is_the_weighted_sum(weights):
    out, batch = random_case()
    losses = multi_objective_loss(out, batch, weights)
    assert set(losses) == {"mask", "joints", "base", "type", "total"}
    expected = sum(weights[k] * losses[k] for k in ("mask", "joints", "base", "type"))
    torch.testing.assert_close(losses["total"], expected)
    torch.testing.assert_close(losses["joints"], joints_loss(out["joints"], batch["joints"], batch["joint_valid"]))


def test_missing_weights_take_the_paper_values_and_unknown_ones_fail():
    out, batch = random_case()
    assert PAPER_WEIGHTS == {"mask": 1.2, "joints": 1.2, "base": 1.2, "type": 0.6}
    torch.testing.assert_close(multi_objective_loss(out, batch, {})["total"],
                               multi_objective_loss(out, batch, PAPER_WEIGHTS)["total"])
    with pytest.raises(ValueError, match="joint"):
        multi_objective_loss(out, batch, {"joint": 1.0})


def test_nan_input_image_fails_the_finite_assertion():
    torch.manual_seed(0)
    model = ArmPoseNet(width=8).eval()
    _, batch = random_case(h=32, w=48)
    batch["image"][0, :, 3, 3] = float("nan")
    with torch.no_grad():
        out = model(batch["image"])
    with pytest.raises(AssertionError, match="total"):
        multi_objective_loss(out, batch, PAPER_WEIGHTS)


def test_nan_label_in_a_valid_slot_fails_the_finite_assertion():
    out, batch = random_case()
    batch["joints"][1, 2, 0] = float("nan")
    with pytest.raises(AssertionError):
        multi_objective_loss(out, batch, PAPER_WEIGHTS)


def test_mask_loss_matches_unweighted_bce_when_classes_are_balanced():
    mask = torch.tensor([[[1, 0], [0, 1]]])
    logits = torch.randn(1, 1, 2, 2)
    expected = 2 * F.binary_cross_entropy_with_logits(logits[:, 0], mask.float())
    assert mask_loss(logits, mask).item() == pytest.approx(expected.item(), rel=1e-6)
