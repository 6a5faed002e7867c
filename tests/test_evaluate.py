"""armpose.evaluate.predict_split: the predicted masks it keeps on request, and the zoom test on the mirror test."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from armpose.data import LabelledFrames, split_indices
from armpose.evaluate import predict_split
from armpose.metrics import mask_counts
from armpose.mirror_test import MirrorAveraged, forward_with_mirror
from armpose.model import build_model
from armpose.robots import get_robot
from armpose.zoom_test import zoom_refine


@pytest.fixture(name="untrained")
def untrained_fixture(tiny_project, one_torch_thread):
    """``(model, data_dir, rows)``: an untrained width-8 network in eval mode and 5 test rows of the tiny project."""
    root, _ = tiny_project
    data_dir = root / "data" / "labels"
    torch.manual_seed(0)
    return build_model({"width": 8}).eval(), data_dir, split_indices(data_dir, "test")[:5]


def test_kept_masks_are_the_ones_scored(untrained):
    model, data_dir, rows = untrained
    frames = LabelledFrames(data_dir, rows)
    with torch.no_grad():   # the median logit as the threshold: an untrained network's masks then hold both values
        logits = model(torch.stack([frames[i]["image"] for i in range(len(frames))]))["mask_logits"]
        model.mask_threshold.fill_(float(logits.median()))
    pred, labelled = predict_split(model, data_dir, rows=rows, batch_size=2, keep_masks=True)
    truth = np.stack([frames[i]["mask"].numpy() > 0.5 for i in range(len(frames))])
    np.testing.assert_array_equal(labelled["masks"], truth)                        # the labels, kept too
    assert pred["masks"].dtype == bool and pred["masks"].shape == truth.shape
    assert 0 < pred["masks"].mean() < 1          # neither all robot nor all background: the check below can fail
    np.testing.assert_array_equal(mask_counts(pred["masks"], truth), pred["mask_counts"])
    plain, plain_truth = predict_split(model, data_dir, rows=rows, batch_size=2)
    assert "masks" not in plain and "masks" not in plain_truth
    np.testing.assert_array_equal(plain["mask_counts"], pred["mask_counts"])


def test_zoom_on_mirror_runs_both_looks_on_the_mirror_test(untrained):
    model, data_dir, rows = untrained
    with pytest.raises(ValueError, match="needs zoom and mirror"):
        predict_split(model, data_dir, rows=rows, zoom=True, zoom_on_mirror=True)
    pred, _ = predict_split(model, data_dir, rows=rows, batch_size=len(rows), mirror=True, zoom=True,
                            zoom_on_mirror=True)
    plain, _ = predict_split(model, data_dir, rows=rows, batch_size=len(rows), mirror=True, zoom=True)
    frames = LabelledFrames(data_dir, rows)
    images = torch.stack([frames[i]["image"] for i in range(len(frames))])
    cams = torch.stack([frames[i]["intrinsics"] for i in range(len(frames))])
    counts = [get_robot(t).num_joints for t in frames.robot_types]
    with torch.no_grad():
        _, mean = forward_with_mirror(model, images, cams[:, 0], cams[:, 2])
        expected = zoom_refine(MirrorAveraged(model, cams[:, 0], cams[:, 2]), images, mean, cams, None, counts,
                               float(model.mask_threshold))
    np.testing.assert_allclose(pred["zoom"]["joints"], expected["joints"].numpy(), atol=1e-5)
    np.testing.assert_allclose(pred["mirror"]["joints"], plain["mirror"]["joints"], atol=1e-6)   # the mirror test itself unchanged
    assert np.abs(pred["zoom"]["joints"] - plain["zoom"]["joints"]).max() > 1e-4              # the flag changes the zoom test
