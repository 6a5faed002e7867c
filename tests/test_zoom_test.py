"""The zoom test (armpose.zoom_test): magnification, mapping back, and an oracle end to end."""
import numpy as np
import pytest
import torch

from armpose.report import option_section
from armpose.zoom_test import (camera_columns, check_max_zoom, forward_with_zoom, magnify, unmagnify, unzoom_points,
                               zoom_average, zoom_for_points, zoom_refine)

W, H = 256, 212
CAM = (309.5, 309.2, 128.0, 105.5)
RADIUS_M = 0.08  # the oracle's ball


def project(p: np.ndarray, cam=CAM) -> np.ndarray:
    fx, fy, cx, cy = cam
    return np.array([fx * p[0] / p[2] + cx, fy * p[1] / p[2] + cy])


def ball_image(points: np.ndarray) -> torch.Tensor:
    """(1, 3, H, W): a white disc of radius ``RADIUS_M`` (metres) at each 3D point, radius in
    pixels ``fx R / z``, supersampled 8x for sub-pixel edges."""
    s = 8
    yy, xx = np.mgrid[0:H * s, 0:W * s]
    xx, yy = (xx + 0.5) / s - 0.5, (yy + 0.5) / s - 0.5
    img = np.zeros((H * s, W * s), np.float32)
    for p in points:
        u, v = project(p)
        img[(xx - u) ** 2 + (yy - v) ** 2 <= (CAM[0] * RADIUS_M / p[2]) ** 2] = 1.0
    img = img.reshape(H, s, W, s).mean((1, 3))
    return torch.from_numpy(np.repeat(img[None, None], 3, 1))


class BallOracle(torch.nn.Module):
    """A "network" that finds the one ball in its input, reads its depth from its apparent size
    with the network camera ``CAM``, and reports it as every joint and the base."""

    def forward(self, images: torch.Tensor) -> dict:
        out = []
        for img in images[:, 0].double():
            area = img.sum()
            yy, xx = torch.meshgrid(torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64),
                                    indexing="ij")
            u, v = (img * xx).sum() / area, (img * yy).sum() / area
            z = CAM[0] * RADIUS_M / torch.sqrt(area / np.pi)
            out.append(torch.stack([(u - CAM[2]) / CAM[0] * z, (v - CAM[3]) / CAM[1] * z, z]))
        p = torch.stack(out).float()
        return {"joints": p[:, None].repeat(1, 7, 1), "base": p, "type_logits": torch.zeros(len(p), 5),
                "mask_logits": images[:, :1] * 8 - 4}


def test_magnify_moves_pixel_p_to_k_p_plus_t():
    img = torch.zeros(1, 1, H, W)
    img[0, 0, 60, 90] = 1.0
    k, t = torch.tensor([1.5]), torch.tensor([[-20.0, 10.0]])
    out = magnify(img, k, t)[0, 0]
    # centroid of the spike, spread over neighbours by the bilinear resampling
    yy, xx = torch.meshgrid(torch.arange(H), torch.arange(W), indexing="ij")
    cu, cv = float((out * xx).sum() / out.sum()), float((out * yy).sum() / out.sum())
    assert cu == pytest.approx(1.5 * 90 - 20, abs=0.05) and cv == pytest.approx(1.5 * 60 + 10, abs=0.05)


def test_unmagnify_inverts_magnify_where_covered():
    img = torch.rand(2, 1, H, W)
    k, t = torch.tensor([1.0, 1.4]), torch.tensor([[0.0, 0.0], [-30.0, -20.0]])
    back, covered = unmagnify(magnify(img, k, t), k, t)
    assert covered[0].all()
    torch.testing.assert_close(back[0], img[0], atol=1e-4, rtol=0)
    inner = covered[1, 0].clone()
    inner[:2], inner[-2:], inner[:, :2], inner[:, -2:] = False, False, False, False
    assert 0.3 < covered[1].float().mean() < 0.8
    # bilinear twice blurs: compare with a smooth image instead of noise
    smooth = torch.linspace(0, 1, W)[None, None, None].expand(1, 1, H, W).contiguous()
    b2, c2 = unmagnify(magnify(smooth, k[1:], t[1:]), k[1:], t[1:])
    err = (b2 - smooth).abs()[c2 & inner[None, None]]
    assert float(err.max()) < 1e-3


def test_unzoom_points_inverts_the_magnified_camera():
    rng = np.random.default_rng(0)
    pts = torch.from_numpy(np.column_stack([rng.uniform(-0.4, 0.4, 5), rng.uniform(-0.3, 0.3, 5),
                                            rng.uniform(1.0, 3.0, 5)]))[None]
    k, t = torch.tensor([1.3], dtype=torch.float64), torch.tensor([[-12.0, 7.5]], dtype=torch.float64)
    fx, fy, cx, cy = CAM
    # what a correct network sees: pixel k p + t, depth z / k, read through its own camera
    u = k * (fx * pts[..., 0] / pts[..., 2] + cx) + t[:, :1]
    v = k * (fy * pts[..., 1] / pts[..., 2] + cy) + t[:, 1:]
    zn = pts[..., 2] / k
    net = torch.stack([(u - cx) / fx * zn, (v - cy) / fy * zn, zn], -1)
    torch.testing.assert_close(unzoom_points(net, k, t, CAM), pts)


def test_zoom_for_points_centres_the_box_and_respects_the_limits():
    near = torch.tensor([[[0.0, 0.0, 2.0], [0.1, 0.05, 2.0]]])         # small: capped at max_zoom
    far = torch.tensor([[[-0.8, -0.6, 1.0], [0.8, 0.6, 1.0]]])        # fills the frame: k = 1
    k, t = zoom_for_points(torch.cat([near, far]), CAM, (W, H), max_zoom=1.5)
    assert k.tolist() == pytest.approx([1.5, 1.0])
    centre = (project(near[0, 0].numpy()) + project(near[0, 1].numpy())) / 2
    assert (k[0] * torch.tensor(centre, dtype=torch.float32) + t[0]).tolist() == pytest.approx([CAM[2], CAM[3]], abs=1e-3)
    with pytest.raises(ValueError, match="max_zoom"):
        zoom_for_points(near, CAM, (W, H), max_zoom=0.5)
    with pytest.raises(ValueError, match="camera"):
        camera_columns(torch.zeros(3, 4), 2, near)


def test_identity_zoom_gives_back_the_single_pass():
    single = {"joints": torch.tensor([[[0.1, -0.2, 2.0]]]), "base": torch.tensor([[0.0, 0.1, 2.2]]),
              "type_logits": torch.tensor([[2.0, 0.0, 0.0, 0.0, 0.0]]), "mask_logits": torch.randn(1, 1, H, W)}
    out = zoom_average(single, single, torch.ones(1), torch.zeros(1, 2), CAM)
    torch.testing.assert_close(out["joints"], single["joints"])
    torch.testing.assert_close(out["base"], single["base"])
    torch.testing.assert_close(out["type_logits"].softmax(-1), single["type_logits"].softmax(-1))
    torch.testing.assert_close(out["mask_logits"], single["mask_logits"], atol=2e-4, rtol=0)


@pytest.mark.parametrize("point", [(0.25, -0.15, 2.4), (-0.5, 0.3, 1.6)])
def test_oracle_on_a_magnified_frame_maps_back_to_the_truth(point):
    """A correct network on the magnified frame, mapped back, gives the true position: the
    zoom test's geometry is exact (to the oracle's pixel-area precision)."""
    p = np.array(point)
    images = ball_image(p[None])
    single, avg = forward_with_zoom(BallOracle(), images, CAM, max_zoom=1.5)
    truth = torch.tensor(point, dtype=torch.float32)
    torch.testing.assert_close(single["base"][0], truth, atol=0.03, rtol=0)
    torch.testing.assert_close(avg["base"][0], truth, atol=0.03, rtol=0)
    torch.testing.assert_close(avg["joints"][0, 3], truth, atol=0.03, rtol=0)
    # the magnified pass alone: undo the averaging
    zoomed_alone = 2 * avg["base"][0] - single["base"][0]
    torch.testing.assert_close(zoomed_alone, truth, atol=0.03, rtol=0)
    assert avg["mask_logits"].shape == (1, 1, H, W)


def test_per_frame_cameras_and_the_valid_points_decide_each_frame_s_box():
    pts = torch.tensor([[[0.0, 0.0, 2.0], [0.1, 0.05, 2.0], [3.0, 2.0, 2.0]]] * 2)
    cams = torch.tensor([CAM, (CAM[0] * 2, CAM[1] * 2, CAM[2], CAM[3])])
    valid = torch.tensor([[True, True, False], [True, True, False]])       # slot 3: an unused joint slot
    k, t = zoom_for_points(pts, cams, (W, H), max_zoom=10.0, valid=valid)
    assert float(k[1]) < float(k[0]) - 1                                 # twice the focal length: a box twice as big
    for row in range(2):                                                 # each box centre lands on its principal point
        cam = tuple(float(c) for c in cams[row])
        centre = (project(pts[row, 0].numpy(), cam) + project(pts[row, 1].numpy(), cam)) / 2
        assert (k[row] * torch.tensor(centre, dtype=torch.float32) + t[row]).tolist() == pytest.approx(
            [CAM[2], CAM[3]], abs=1e-3)
    k_all, _ = zoom_for_points(pts, cams, (W, H), max_zoom=10.0)
    assert (k_all < k).all()                                             # the far slot would have widened the box
    for bad in (0.5, "2", True):
        with pytest.raises(ValueError, match="max_zoom"):
            check_max_zoom(bad)


def test_zoom_refine_with_joint_counts_ignores_the_unused_slot():
    p = np.array([0.1, -0.05, 2.0])
    images = ball_image(p[None])
    oracle = BallOracle()
    single = oracle(images)
    single["joints"][:, 6] = torch.tensor([5.0, 5.0, 2.0])               # slot 7, unused by a 6-joint robot
    single["type_logits"][:, 0] = 5.0                                    # predicted type 0: 6 joints
    avg = zoom_refine(oracle, images, single, CAM, max_zoom=1.5, joint_counts=[6, 6, 6, 7, 7])
    torch.testing.assert_close(avg["base"][0], torch.tensor(p, dtype=torch.float32), atol=0.03, rtol=0)


def test_report_section_lists_single_and_zoom_per_family():
    fam = {"joint_median_cm": 14.3, "base_median_cm": 12.6, "type_accuracy": 0.902, "mask_accuracy": 0.992}
    zoomed = {**fam, "type_accuracy": 0.92}
    text = "\n".join(option_section("zoom_test", {"UR": fam}, {"by_family": {"UR": zoomed}},
                                    {"cpu": {"batch1_median_ms": 11.8, "zoom_batch1_median_ms": 29.9}}))
    assert "## Zoom test" in text and "| UR | 14.30 / 14.30 | 12.60 / 12.60 | 90.2 / 92.0 | 99.2 / 99.2 |" in text
    assert "11.8 ms single, 29.9 ms with the zoom test" in text
