"""The mirror test: exact un-mirroring of points and masks, and averaging that cancels a mirror-antisymmetric error."""
import numpy as np
import pytest
import torch
from torch import nn

from armpose.mirror_test import MirrorAveraged, forward_with_mirror, mirror_average, unmirror_points
from armpose.report import option_section

W, H, FX, FY, CX, CY = 64, 48, 60.0, 60.0, 33.0, 22.5     # principal point off the centre column (31.5)


def project_u(p: np.ndarray, fx: float = FX, cx: float = CX) -> np.ndarray:
    return fx * p[..., 0] / p[..., 2] + cx


def test_unmirrored_points_land_on_the_mirrored_pixel_column_at_the_same_depth():
    rng = np.random.default_rng(0)
    truth = rng.uniform([-0.5, -0.4, 1.0], [0.5, 0.4, 3.0], (20, 3))
    u_mirror = (W - 1) - project_u(truth)                         # where the mirror shows each point
    seen = truth.copy()
    seen[:, 0] = (u_mirror - CX) * truth[:, 2] / FX               # what a perfect network reports on the mirror
    back = unmirror_points(torch.from_numpy(seen), FX, CX, W).numpy()
    np.testing.assert_allclose(back, truth, atol=1e-12)
    # with the principal point on the centre column, un-mirroring is x -> -x
    centred = unmirror_points(torch.from_numpy(truth), FX, (W - 1) / 2, W).numpy()
    np.testing.assert_allclose(centred, truth * [-1, 1, 1], atol=1e-12)


def test_per_frame_cameras_broadcast_over_joints():
    pts = torch.tensor([[[0.1, 0.0, 2.0]] * 3, [[0.1, 0.0, 2.0]] * 3], dtype=torch.float64)   # (2, 3, 3)
    out = unmirror_points(pts, torch.tensor([60.0, 120.0]), torch.tensor([31.5, 33.0]), W)
    np.testing.assert_allclose(out[0, :, 0].numpy(), -0.1)
    np.testing.assert_allclose(out[1, :, 0].numpy(), (W - 1 - 66.0) * 2.0 / 120.0 - 0.1)


class BiasedBlobNet(nn.Module):
    """A stand-in network: each image's bright-blob centroid, back-projected at depth ``z``, with
    a constant error ``bias`` (metres) added to x: the kind of error that flips sign on the
    mirror. Type logits favour class 0 on the left half of the image, 1 on the right."""

    def __init__(self, z: float = 2.0, bias: float = 0.05):
        super().__init__()
        self.z, self.bias = z, bias

    def forward(self, x):
        gray = x.float().mean(1)                                            # (B, H, W)
        xs = torch.arange(gray.shape[-1], dtype=torch.float64)
        ys = torch.arange(gray.shape[-2], dtype=torch.float64)
        s = gray.double().sum((1, 2))
        u = (gray.double().sum(1) * xs).sum(1) / s
        v = (gray.double().sum(2) * ys).sum(1) / s
        p = torch.stack([(u - CX) / FX * self.z + self.bias, (v - CY) / FY * self.z,
                         torch.full_like(u, self.z)], -1)
        side = (u - (W - 1) / 2) / W
        return {"joints": p[:, None].expand(-1, 7, 3).clone(), "base": p.clone(),
                "type_logits": torch.stack([-side, side, torch.zeros_like(side)], -1) * 10,
                "mask_logits": (gray[:, None] > 0.5).float() * 20 - 10}


def blob_images(points: np.ndarray) -> torch.Tensor:
    ys, xs = np.mgrid[0:H, 0:W]
    out = []
    for p in points:
        u, v = project_u(p), FY * p[1] / p[2] + CY
        disc = np.clip(3.5 - np.hypot(xs - u, ys - v), 0, 1)
        out.append(np.repeat(disc[None], 3, 0))
    return torch.from_numpy(np.stack(out)).float()


@pytest.fixture(name="pair")
def pair_fixture():
    points = np.array([[0.3, -0.1, 2.0], [-0.4, 0.2, 2.0], [0.05, 0.25, 2.0]])
    with torch.no_grad():
        single, mean = forward_with_mirror(BiasedBlobNet(), blob_images(points), FX, CX)
    return points, single, mean


def test_mirror_average_cancels_an_error_that_flips_with_the_mirror(pair):
    points, single, mean = pair
    err_single = np.abs(single["base"].numpy() - points)[:, 0]
    err_mean = np.abs(mean["base"].numpy() - points)[:, 0]
    assert np.all(err_single > 0.045)                    # the 5 cm bias
    assert np.all(err_mean < 0.005), err_mean           # gone, up to blob rasterisation
    np.testing.assert_allclose(mean["joints"].numpy()[:, 3], mean["base"].numpy())


def test_mask_is_mirrored_back_and_type_probabilities_are_averaged(pair):
    points, single, mean = pair
    same = (mean["mask_logits"] > 0) == (single["mask_logits"] > 0)
    assert same.float().mean() > 0.99
    probs = mean["type_logits"].softmax(-1)
    np.testing.assert_allclose(probs.sum(-1).numpy(), 1.0, atol=1e-6)
    mirrored = BiasedBlobNet()(blob_images(points).flip(-1))["type_logits"].softmax(-1)
    np.testing.assert_allclose(probs.numpy(), ((single["type_logits"].softmax(-1) + mirrored) / 2).numpy(), atol=1e-6)


def test_mirror_average_without_mask_logits():
    out = mirror_average({"joints": torch.zeros(1, 2, 3) + torch.tensor([0.0, 0.0, 2.0]),
                          "base": torch.tensor([[0.0, 0.0, 2.0]]), "type_logits": torch.zeros(1, 5)},
                         {"joints": torch.zeros(1, 2, 3) + torch.tensor([0.0, 0.0, 2.0]),
                          "base": torch.tensor([[0.0, 0.0, 2.0]]), "type_logits": torch.zeros(1, 5)},
                         FX, (W - 1) / 2, W)
    assert set(out) == {"joints", "base", "type_logits"}
    np.testing.assert_allclose(out["type_logits"].softmax(-1).numpy(), 0.2, atol=1e-6)


def test_report_section_lists_single_and_mirror_per_family():
    fam = {"joint_median_cm": 19.5, "base_median_cm": 17.7, "type_accuracy": 0.844, "mask_accuracy": 0.994}
    better = {**fam, "joint_median_cm": 19.1}
    lines = option_section("mirror_test", {"UR": fam}, {"by_family": {"UR": better}},
                           {"cpu": {"batch1_median_ms": 8.3, "mirror_batch1_median_ms": 14.2}})
    text = "\n".join(lines)
    assert "| UR | 19.50 / 19.10 | 17.70 / 17.70 | 84.4 / 84.4 | 99.4 / 99.4 |" in text
    assert "8.3 ms single, 14.2 ms with the mirror test" in text
    assert option_section("mirror_test", {"UR": fam}, {}, {}) == []


def test_mirror_averaged_module_runs_the_mirror_test_on_every_call(pair):
    points, _, mean = pair
    net = BiasedBlobNet()
    net.mask_threshold = torch.tensor(1.5)
    wrapped = MirrorAveraged(net, FX, CX)
    with torch.no_grad():
        out = wrapped(blob_images(points))
    for key in ("joints", "base", "type_logits", "mask_logits"):
        torch.testing.assert_close(out[key], mean[key])
    assert float(wrapped.mask_threshold) == 1.5
    assert MirrorAveraged(BiasedBlobNet(), FX, CX).mask_threshold is None   # a module without one: threshold 0
