"""armpose.features: the frozen-trunk cache holds each frame and, with a zoom, its zoom view."""
import numpy as np
import torch

from armpose.data import LabelledFrames
from armpose.features import batch_features, cache_trunk_features, cached_views
from armpose.model import build_model

ZOOM = {"p": 0.5, "fill": [0.55, 0.85], "max_zoom": 2.5}


def test_cache_holds_plain_and_zoom_views_with_their_own_labels(tiny_project):
    root, _ = tiny_project
    data = root / "data" / "labels"
    rows = np.arange(6)
    plain = LabelledFrames(data, rows, augment={"brightness": 0.2})
    assert len(cached_views(plain)) == 1
    frames = LabelledFrames(data, rows, augment={"brightness": 0.2, "zoom": ZOOM}, seed=3)
    views = cached_views(frames)
    assert len(views) == 2 and views[1].augment["zoom"]["p"] == 1.0
    model = build_model({"width": 8}).eval()
    cache = cache_trunk_features(model, frames, "cpu", batch_size=4, disable_bar=True)
    assert len(cache) == 12
    first, second = cache[2], cache[6 + 2]
    assert int(first["index"]) == int(second["index"]) == 2
    np.testing.assert_array_equal(first["joints"].numpy(), LabelledFrames(data, rows)[2]["joints"].numpy())
    zoomed = views[1][2]
    np.testing.assert_array_equal(second["joints"].numpy(), zoomed["joints"].numpy())
    assert not torch.equal(first["joints"], second["joints"])
    with torch.no_grad():
        expect = model.trunk_features(zoomed["image"][None].contiguous(memory_format=torch.channels_last))
    got = batch_features({k: v[None] for k, v in second.items()})
    for g, e in zip(got, expect):
        torch.testing.assert_close(g, e.to(torch.float16).float(), atol=1e-3, rtol=1e-3)   # batch of 4 against 1
