"""armpose.viz: projection, overlays and label statistics."""
from __future__ import annotations

import io

import numpy as np
import pytest
from matplotlib.figure import Figure

from armpose import viz
from armpose.geometry import Camera


def test_project_matches_pinhole_formula_and_camera():
    cam = Camera(256, 212, 309.5, 309.2, 128.0, 105.5)
    intr = np.array([cam.fx, cam.fy, cam.cx, cam.cy])
    p = np.array([[0.0, 0.0, 2.0], [0.2, -0.1, 1.5], [-0.5, 0.3, 3.0]])
    uv = viz.project(p, intr)
    assert uv.shape == (3, 2)
    np.testing.assert_allclose(uv[0], [128.0, 105.5])
    np.testing.assert_allclose(uv[1], [309.5 * 0.2 / 1.5 + 128.0, 309.2 * -0.1 / 1.5 + 105.5])
    np.testing.assert_allclose(uv, cam.project(p))
    np.testing.assert_allclose(viz.project(p[1], intr), uv[1])


def test_project_broadcasts_per_frame_intrinsics_and_drops_points_behind():
    rng = np.random.default_rng(0)
    joints = rng.uniform(-0.5, 0.5, (4, 7, 3)) + [0, 0, 2.0]
    intr = np.array([[300, 300, 128, 106], [310, 305, 120, 100], [250, 260, 128, 106], [400, 400, 0, 0]], float)
    uv = viz.project(joints, intr)
    assert uv.shape == (4, 7, 2)
    for n in range(4):
        np.testing.assert_allclose(uv[n], viz.project(joints[n], intr[n]))
    behind = viz.project(np.array([[0.1, 0.1, -1.0], [0.1, 0.1, 0.0]]), intr[0])
    assert np.isnan(behind).all()
    with pytest.raises(ValueError):
        viz.project(np.zeros((2, 2)), intr[0])


def test_overlay_labels_shape_and_content():
    img = np.full((212, 256, 3), 100, np.uint8)
    mask = np.zeros((212, 256), np.uint8)
    mask[50:80, 60:90] = 1
    joints = np.array([[100.0, 100.0], [150.0, 60.0], [np.nan, np.nan]])
    out = viz.overlay_labels(img, mask, joints, np.array([80.0, 150.0]), joint_valid=[True, True, False])
    assert out.shape == img.shape and out.dtype == np.uint8
    assert (img == 100).all(), "the input image must not be modified"
    assert (out[60, 70] != 100).any() and out[60, 70, 0] > out[60, 70, 1]      # tinted red
    assert (out[5, 5] == 100).all()                                           # background untouched
    assert (out[100, 100] != 100).any() and (out[60, 150] != 100).any()       # joints drawn
    assert (out[150, 80 + 4] != 100).any()                                    # base square outline
    bare = viz.overlay_labels(img, None, None, None)
    assert (bare == img).all()
    with pytest.raises(ValueError):
        viz.overlay_labels(img, mask[:10], joints, None)


def _toy_dataset():
    n = 6
    masks = np.zeros((n, 10, 10), np.uint8)
    for i in range(n):
        masks[i, : i + 1] = 1                                                 # (i+1) * 10 % of the image
    arrays = {"masks": masks, "robot": np.array([0, 0, 1, 1, 1, 2]), "split": np.array([0, 1, 0, 0, 1, 0]),
              "distance": np.linspace(1.2, 3.0, n)}
    index = {"robot_types": ["ur5", "iiwa", "panda", "ur3"]}
    return arrays, index


def test_mask_area_by_robot_and_summaries():
    arrays, index = _toy_dataset()
    areas = viz.mask_area_by_robot(arrays, index)
    assert list(areas) == ["ur5", "iiwa", "panda"]                           # ur3 has no frames
    np.testing.assert_allclose(areas["ur5"], [0.1, 0.2])
    np.testing.assert_allclose(areas["iiwa"], [0.3, 0.4, 0.5])
    np.testing.assert_allclose(viz.mask_area_fraction(arrays["masks"], chunk=4), np.arange(1, 7) / 10)
    rows = viz.mask_area_summary(areas)
    assert rows[0]["family"] == "UR" and rows[0]["paper"] == viz.PAPER_MASK_AREA["UR"]
    assert rows[0]["in_paper_range"] == pytest.approx(0.5)                   # 0.1 in, 0.2 out of 6-17 %
    assert "ur5" in viz.format_table(rows, percent=("median",))
    counts = viz.split_counts(arrays, index)
    assert counts[0] == {"robot": "ur5", "train": 1, "test": 1, "test_fraction": 0.5}
    assert counts[-1]["robot"] == "all" and counts[-1]["train"] + counts[-1]["test"] == 6


def test_figures_render_with_agg():
    arrays, index = _toy_dataset()
    imgs = [np.zeros((21, 25, 3), np.uint8)] * 5
    figs = [viz.sample_grid(imgs, [str(i) for i in range(5)], ncols=2),
            viz.mask_area_figure(viz.mask_area_by_robot(arrays, index)),
            viz.distance_histogram(arrays, index)]
    for fig in figs:
        assert isinstance(fig, Figure)
        buf = io.BytesIO()
        fig.savefig(buf, format="png")
        assert buf.getvalue()[:4] == b"\x89PNG"


ZOOM = {"p": 1.0, "fill": [0.55, 0.85], "max_zoom": 2.5, "centre_jitter": 0.0, "scale_jitter": 0.0}


@pytest.mark.parametrize("zoom", [None, ZOOM])
def test_augmentation_figure_shows_labels_that_follow_the_warp(tiny_project, zoom):
    """On real renders: after a camera turn, mirror and dolly (or a zoom to the robot), the
    projected joints still sit on the (warped) robot mask, and the figure holds the stored
    frame plus one per epoch. A zoom without jitter centres the labels' box and fills the frame."""
    import cv2
    from armpose.augment import points_box
    from armpose.data import LabelledFrames

    root, _ = tiny_project
    data = root / "data" / "labels"
    augment = {"flip": 0.5, "rotate_deg": 5.0, "roll_deg": 8.0, "dolly": 0.15, "zoom": zoom}
    rows = [0, 5]
    images, titles = viz.augmented_samples(data, rows, augment, seed=1, epochs=2)
    assert len(images) == len(titles) == 6 and "as stored" in titles[0] and "epoch 1" in titles[2]
    ds = LabelledFrames(data, np.arange(12), augment=augment, seed=1)
    on_robot = []
    for row in range(12):
        for epoch in range(2):
            item = ds[(row, epoch)]
            mask = cv2.dilate(item["mask"].numpy().astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
            uv = viz.project(item["joints"].numpy()[item["joint_valid"].numpy()], item["intrinsics"].numpy())
            h, w = mask.shape
            inside = (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1)
            on_robot += list(mask[np.round(uv[inside, 1]).astype(int), np.round(uv[inside, 0]).astype(int)])
            if zoom:
                points = np.vstack([item["base"].numpy()[None], item["joints"].numpy()[item["joint_valid"].numpy()]])
                centre, extent = points_box(points, item["intrinsics"].numpy())
                assert np.abs(centre - item["intrinsics"].numpy()[2:]).max() < 0.1 * extent.max()
                assert max(extent[0] / w, extent[1] / h) < 0.9
    assert len(on_robot) > 50 and np.mean(on_robot) > 0.9
    assert isinstance(viz.augmentation_figure(data, rows, augment, epochs=1), Figure)


def test_chw_to_uint8_rounds_clips_and_moves_channels_last():
    from armpose.viz import chw_to_uint8
    img = np.zeros((3, 2, 4), np.float32)
    img[0, 0, 0], img[1, 1, 3], img[2, 0, 1] = 1.0, 0.5, 1.7
    img[0, 1, 2] = -0.2
    out = chw_to_uint8(img)
    assert out.shape == (2, 4, 3) and out.dtype == np.uint8
    assert out[0, 0, 0] == 255 and out[1, 3, 1] == 128 and out[0, 1, 2] == 255 and out[1, 2, 0] == 0
