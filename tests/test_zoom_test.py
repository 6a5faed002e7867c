"""The zoom test (armpose.zoom_test): the second look's view, mapping back, and an oracle end to end."""
import numpy as np
import pytest
import torch

from armpose.report import option_section
from armpose.augment import dolly_points, points_box, rotate_points
from armpose.zoom_test import (DEFAULT_SETTINGS, TRAINED_WEIGHT, camera_rows, check_max_zoom, forward_with_zoom,
                               settings_from_config, unwarp_maps, unzoom_points, warp_images, zoom_combine,
                               zoom_refine, zoom_views)

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


ONE = {"fill": 0.6, "max_zoom": 3.0, "weight": 1.0}   # the second look alone


def random_views(rng, n):
    """n (turn, scale) pairs of the kind the zoom test makes: a rotation of up to ~15 degrees, scale 1-3."""
    turns = []
    for _ in range(n):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        a = rng.uniform(0, np.radians(15))
        Kx = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        turns.append(np.eye(3) + np.sin(a) * Kx + (1 - np.cos(a)) * Kx @ Kx)
    return np.stack(turns), rng.uniform(1.0, 3.0, n)


def test_unzoom_points_inverts_the_training_labels_transform():
    """Training labels of a zoomed view are rotate_points then dolly_points about the joints' mean
    depth; unzoom_points with the view's own mean joint depth gives back the original points."""
    rng = np.random.default_rng(0)
    turns, scales = random_views(rng, 4)
    pts = np.column_stack([rng.uniform(-0.6, 0.6, (4 * 8, 2)), rng.uniform(2.0, 2.8, 4 * 8)]).reshape(4, 8, 3)
    viewed, z_ref_after = [], []
    for p, M, s in zip(pts, turns, scales):
        turned = rotate_points(p, M)
        v = dolly_points(turned, s, turned[:7, 2].mean())         # slots 0-6 joints, 7 the base
        viewed.append(v)
        z_ref_after.append(v[:7, 2].mean())
    back = unzoom_points(torch.tensor(np.stack(viewed)), turns, scales, np.array(z_ref_after))
    np.testing.assert_allclose(back.numpy(), pts, atol=1e-9)


def test_zoom_views_centre_the_box_and_make_it_fill_the_frame():
    cams = camera_rows(CAM, 3)
    pts = np.array([[[0.1, -0.5, 2.0], [0.7, 0.3, 2.2], [0.4, 0.0, 2.1]],      # off-centre: fill 0.6
                    [[0.0, 0.0, 2.0], [0.01, 0.01, 2.0], [0.0, 0.01, 2.0]],    # tiny: capped at max_zoom
                    [[-1.2, -0.8, 2.0], [1.2, 0.8, 2.0], [0.0, 0.0, 2.0]]])    # fills the frame: never shrunk
    valid = np.ones((3, 3), bool)
    turns, scales = zoom_views(pts, valid, cams, (W, H), 0.6, 2.5)
    assert scales[1] == 2.5 and scales[2] == 1.0 and 1.0 < scales[0] < 2.5
    centre, _ = points_box(pts[0], CAM)                                        # the ray through the box centre ...
    ray = np.array([(centre[0] - CAM[2]) / CAM[0], (centre[1] - CAM[3]) / CAM[1], 1.0])
    np.testing.assert_allclose(project(turns[0] @ ray, CAM), [CAM[2], CAM[3]], atol=1e-9)   # ... is the new axis
    turned = rotate_points(pts[0], turns[0])
    viewed = dolly_points(turned, scales[0], turned[:, 2].mean())
    _, extent_after = points_box(viewed, CAM)
    assert max(extent_after[0] / W, extent_after[1] / H) == pytest.approx(0.6, abs=1e-6)
    for bad in (0.5, "2", True):
        with pytest.raises(ValueError, match="max_zoom"):
            check_max_zoom(bad)
    with pytest.raises(ValueError, match="camera"):
        camera_rows(np.zeros((3, 4)), 2)


def test_warped_maps_come_back_where_the_view_covers_them():
    rng = np.random.default_rng(1)
    yy, xx = np.mgrid[0:H, 0:W]
    smooth = torch.tensor(np.sin(xx / 17.0) + np.cos(yy / 11.0), dtype=torch.float32)[None, None].repeat(2, 1, 1, 1)
    turns, scales = random_views(rng, 2)
    cams = camera_rows(CAM, 2)
    views = warp_images(smooth, turns, scales, cams)
    back, covered = unwarp_maps(views, turns, scales, cams)
    inner = covered.clone()
    inner[..., :3, :] = inner[..., -3:, :] = inner[..., :, :3] = inner[..., :, -3:] = False
    assert covered.float().mean() > 0.1
    err = (back - smooth).abs()[inner & (torch.roll(covered, 3, -1) & torch.roll(covered, -3, -1)
                                         & torch.roll(covered, 3, -2) & torch.roll(covered, -3, -2))]
    assert float(err.max()) < 0.05                                             # bilinear twice on a smooth map


@pytest.mark.parametrize("point", [(0.25, -0.15, 2.4), (-0.5, 0.3, 1.6)])
def test_oracle_on_the_second_look_maps_back_to_the_truth(point):
    """A correct network on the turned, dollied view, mapped back, gives the true position: the
    zoom test's geometry is exact (to the oracle's pixel-area precision)."""
    p = np.array(point)
    images = ball_image(p[None])
    single, zoomed = forward_with_zoom(BallOracle(), images, CAM, ONE)
    truth = torch.tensor(point, dtype=torch.float32)
    torch.testing.assert_close(single["base"][0], truth, atol=0.03, rtol=0)
    # 4 % of the depth: the test image draws each ball as a disc of radius f R / z wherever it is,
    # not as a sphere's projection, so turning the camera to it changes its area a little
    torch.testing.assert_close(zoomed["base"][0], truth, atol=0.04 * p[2], rtol=0)
    torch.testing.assert_close(zoomed["joints"][0, 3], truth, atol=0.04 * p[2], rtol=0)
    assert zoomed["mask_logits"].shape == (1, 1, H, W)


def test_identity_view_and_weights_combine_as_a_weighted_mean():
    single = {"joints": torch.tensor([[[0.1, -0.2, 2.0]] * 7]), "base": torch.tensor([[0.0, 0.1, 2.2]]),
              "type_logits": torch.tensor([[2.0, 0.0, 0.0, 0.0, 0.0]]), "mask_logits": torch.randn(1, 1, H, W)}
    other = {"joints": single["joints"] + 0.1, "base": single["base"] + 0.1,
             "type_logits": torch.tensor([[0.0, 2.0, 0.0, 0.0, 0.0]]), "mask_logits": single["mask_logits"]}
    eye, one = np.eye(3)[None], np.ones(1)
    same = zoom_combine(single, single, eye, one, camera_rows(CAM, 1), weight=0.5)
    torch.testing.assert_close(same["joints"], single["joints"])
    torch.testing.assert_close(same["mask_logits"], single["mask_logits"], atol=1e-5, rtol=0)
    mixed = zoom_combine(single, other, eye, one, camera_rows(CAM, 1), weight=0.25)
    torch.testing.assert_close(mixed["base"], single["base"] + 0.025)
    probs = 0.75 * single["type_logits"].softmax(-1) + 0.25 * other["type_logits"].softmax(-1)
    torch.testing.assert_close(mixed["type_logits"].softmax(-1), probs)


def test_second_look_mask_logits_are_moved_to_the_first_pass_offset():
    """At scale s the robot's share of the view is s^2 times the first pass's; the class-balanced
    loss offsets the logits by log((1 - pi) / pi), so the second look's are shifted to match."""
    first = torch.full((1, 1, H, W), -5.0)
    first[..., 90:110, 110:140] = 5.0                                          # 600 px robot
    pi = 600 / (H * W)
    single = {"joints": torch.tensor([[[0.0, 0.0, 2.0]] * 7]), "base": torch.tensor([[0.0, 0.0, 2.0]]),
              "type_logits": torch.zeros(1, 5), "mask_logits": first}
    zoomed = {**single, "mask_logits": torch.zeros(1, 1, H, W)}
    out = zoom_combine(single, zoomed, np.eye(3)[None], np.array([2.0]), camera_rows(CAM, 1), 0.0, weight=1.0)
    pi2 = 4 * pi
    expected = np.log((1 - pi) / pi) - np.log((1 - pi2) / pi2)
    centre = out["mask_logits"][0, 0, 100, 128]
    assert float(centre) == pytest.approx(expected, rel=1e-4)
    assert float(out["mask_logits"][0, 0, 2, 2]) == -5.0                     # outside the view: the first pass


def test_zoom_refine_with_joint_counts_ignores_the_unused_slot():
    p = np.array([0.1, -0.05, 2.0])
    images = ball_image(p[None])
    oracle = BallOracle()
    single = oracle(images)
    single["joints"][:, 6] = torch.tensor([5.0, 5.0, 2.0])               # slot 7, unused by a 6-joint robot
    single["type_logits"][:, 0] = 5.0                                    # predicted type 0: 6 joints
    out = zoom_refine(oracle, images, single, CAM, ONE, joint_counts=[6, 6, 6, 7, 7])
    torch.testing.assert_close(out["base"][0], torch.tensor(p, dtype=torch.float32), atol=0.02 * p[2], rtol=0)


def test_settings_come_from_the_checkpoint_s_training_config():
    assert settings_from_config({}) == DEFAULT_SETTINGS
    cfg = {"cfg": {"augment": {"flip": 0.5, "zoom": {"p": 0.5, "fill": [0.5, 0.8], "max_zoom": 2.0}}}}
    st = settings_from_config(cfg)
    assert st == {"fill": pytest.approx(0.65), "max_zoom": 2.0, "weight": TRAINED_WEIGHT}
    off = {"cfg": {"augment": {"zoom": {"p": 0.0}}}}
    assert settings_from_config(off) == DEFAULT_SETTINGS
    with pytest.raises(ValueError, match="zoom"):
        settings_from_config({"cfg": {"augment": {"zoom": {"p": 0.5, "fill": [0.9, 0.2]}}}})


def test_report_section_lists_single_and_zoom_per_family():
    fam = {"joint_median_cm": 14.3, "base_median_cm": 12.6, "type_accuracy": 0.902, "mask_accuracy": 0.992}
    zoomed = {**fam, "type_accuracy": 0.92}
    text = "\n".join(option_section("zoom_test", {"UR": fam}, {"by_family": {"UR": zoomed}},
                                    {"cpu": {"batch1_median_ms": 11.8, "zoom_batch1_median_ms": 29.9}}))
    assert "## Zoom test" in text and "| UR | 14.30 / 14.30 | 12.60 / 12.60 | 90.2 / 92.0 | 99.2 / 99.2 |" in text
    assert "11.8 ms single, 29.9 ms with the zoom test" in text


def test_report_section_names_the_mirror_when_the_zoom_test_ran_on_it():
    fam = {"joint_median_cm": 14.3, "base_median_cm": 12.6, "type_accuracy": 0.902, "mask_accuracy": 0.992}
    latency = {"cpu": {"batch1_median_ms": 5.0, "zoom_batch1_median_ms": 25.0, "fit_batch1_median_ms": 70.0}}
    for key, command, phrase in (("zoom_test", "`armpose predict --mirror --zoom`", "with the mirror and zoom tests."),
                                 ("kinematic_fit", "`armpose predict --mirror --zoom --fit`",
                                  "with the mirror and zoom tests and the fit.")):
        mirrored = "\n".join(option_section(key, {"UR": fam}, {"by_family": {"UR": fam}, "on_mirror_test": True}, latency))
        plain = "\n".join(option_section(key, {"UR": fam}, {"by_family": {"UR": fam}}, latency))
        assert command in mirrored and phrase in mirrored and "MirrorAveraged" in mirrored
        assert command not in plain and "mirror" not in plain
    for on_mirror, passes in ((True, "on mirror-averaged passes"), (False, "on single passes")):
        section = {"by_family": {"UR": fam}, "on_mirror_test": True, "sigmas_on_mirror_test": on_mirror}
        assert passes in "\n".join(option_section("kinematic_fit", {"UR": fam}, section, latency))
