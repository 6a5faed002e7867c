"""armpose.evaluate.predict_split: the predicted masks it keeps on request."""
from __future__ import annotations

import numpy as np
import torch

from armpose.data import LabelledFrames, split_indices
from armpose.evaluate import predict_split
from armpose.metrics import mask_counts
from armpose.model import build_model


def test_kept_masks_are_the_ones_scored(tiny_project, one_torch_thread):
    root, _ = tiny_project
    data_dir = root / "data" / "labels"
    torch.manual_seed(0)
    model = build_model({"width": 8}).eval()
    rows = split_indices(data_dir, "test")[:5]
    frames = LabelledFrames(data_dir, rows)
    with torch.no_grad():   # the median logit as the threshold: an untrained network's masks then hold both values
        logits = model(torch.stack([frames[i]["image"] for i in range(len(frames))]))["mask_logits"]
        model.mask_threshold.fill_(float(logits.median()))
    pred, _ = predict_split(model, data_dir, rows=rows, batch_size=2, keep_masks=True)
    truth = np.stack([frames[i]["mask"].numpy() > 0.5 for i in range(len(frames))])
    assert pred["masks"].dtype == bool and pred["masks"].shape == truth.shape
    assert 0 < pred["masks"].mean() < 1          # neither all robot nor all background: the check below can fail
    np.testing.assert_array_equal(mask_counts(pred["masks"], truth), pred["mask_counts"])
    plain, _ = predict_split(model, data_dir, rows=rows, batch_size=2)
    assert "masks" not in plain
    np.testing.assert_array_equal(plain["mask_counts"], pred["mask_counts"])
