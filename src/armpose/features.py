"""Frozen-trunk feature cache: how a run that trains the heads only (transfer stage 1) is cheap.

When every trainable group sits after the trunk and the mask decoder is frozen too, the
trunk's output for a frame never changes during the run (its BatchNorm layers are in eval
mode). :func:`cache_trunk_features` runs the trunk once over the training frames, without
augmentation (and, when the stage's ``augment`` has a ``zoom``, once more over each frame's
zoom view, the zoom test's second look, with its labels: :func:`cached_views`), and
:class:`CachedFeatureFrames` serves them (``feat0``, ``feat1``, ...: what
:meth:`armpose.model.ArmPoseNet.trunk_features` gives, ``[c2, c3, c4]``, or ``[c1, c2, c3, c4]``
with stride-4 keypoint heads) with the labels, so a step is the heads' forward and backward
only; :func:`batch_features` turns a batch back into the list the model takes. The mask term drops out (its branch is frozen);
validation still runs the whole network on images.

The cache lives in memory as float16: c2, c3 and c4 are about 98,000 values per frame at
width 32 and 256x212 (196 kB), 490 MB for the 2,500 frames of the default transfer set;
stride-4 keypoint heads add c1 and double that; zoom views double it again.
"""
from __future__ import annotations

import logging

import numpy as np
import torch
from torch.utils.data import Dataset
from tqdm import tqdm

from armpose.augment import zoom_config
from armpose.data import LabelledFrames

log = logging.getLogger(__name__)

TRUNK_GROUPS = ("trunk", "mask_decoder")
CACHE_DTYPE = torch.float16  # halves the memory; the heads read it back as float32
FEATURE_KEY = "feat"         # batch keys feat0, feat1, ...: the cached trunk features in order


def batch_features(batch: dict) -> list[torch.Tensor]:
    """The cached trunk features of a (collated) :class:`CachedFeatureFrames` batch, in the
    order :meth:`armpose.model.ArmPoseNet.forward` takes them as ``features``."""
    count = sum(1 for k in batch if k.startswith(FEATURE_KEY) and k[len(FEATURE_KEY):].isdigit())
    return [batch[f"{FEATURE_KEY}{j}"] for j in range(count)]


def trunk_is_frozen(trainable: list[str]) -> bool:
    """True when no trainable group is in the trunk or the mask decoder."""
    return not any(g.split(".")[0] in TRUNK_GROUPS for g in trainable)


LABEL_KEYS = ("joints", "joint_valid", "base", "robot", "intrinsics", "image_size", "index")


def cached_views(frames: LabelledFrames) -> list[LabelledFrames]:
    """The views of ``frames`` whose trunk features a cache holds: every frame as stored and,
    when ``frames.augment`` has a ``zoom``, every frame's zoom view too (drawn with probability
    one for epoch 0, no other augmentation), so heads trained on the cache learn the second look."""
    plain = LabelledFrames(frames.folder, frames.indices)
    zcfg = zoom_config(frames.augment or {})
    if zcfg is None:
        return [plain]
    return [plain, LabelledFrames(frames.folder, frames.indices, augment={"zoom": {**zcfg, "p": 1.0}}, seed=frames.seed)]


@torch.no_grad()
def cache_trunk_features(model, frames: LabelledFrames, device, batch_size: int = 32,
                         disable_bar: bool = False) -> "CachedFeatureFrames":
    """The trunk features (:meth:`armpose.model.ArmPoseNet.trunk_features`, as CPU
    :data:`CACHE_DTYPE` tensors ``(N, C, h, w)``) and labels of every view of
    :func:`cached_views`, in order, as a :class:`CachedFeatureFrames`. ``model`` is an
    unwrapped :class:`ArmPoseNet`."""
    was_training = model.training
    model.eval()
    parts: list[list[torch.Tensor]] = []
    labels: dict[str, list[torch.Tensor]] = {k: [] for k in LABEL_KEYS}
    for view in cached_views(frames):
        for start in tqdm(range(0, len(view), batch_size), desc="caching trunk features", unit="batch",
                          disable=disable_bar, dynamic_ncols=True):
            items = [view[i] for i in range(start, min(start + batch_size, len(view)))]
            images = torch.stack([it["image"] for it in items]).to(device).contiguous(memory_format=torch.channels_last)
            parts.append([f.to(CACHE_DTYPE).cpu().contiguous() for f in model.trunk_features(images)])
            for k in LABEL_KEYS:
                labels[k] += [it[k] for it in items]
    model.train(was_training)
    feats = [torch.cat([p[i] for p in parts]) for i in range(len(parts[0]))] if parts else []
    log.info("cached trunk features of %d views: %.0f MB", len(labels["index"]),
             sum(f.numel() * f.element_size() for f in feats) / 1e6)
    return CachedFeatureFrames(frames, feats, {k: torch.stack(v) for k, v in labels.items() if v})


class CachedFeatureFrames(Dataset):
    """Cached trunk features (``feat0``, ``feat1``, ...) with the labels of their views, in the
    order of ``cache``: the items of ``frames`` without ``image`` and ``mask``. Works with
    :func:`armpose.data.make_loader`; ``frames`` passes the loader's epoch on."""

    def __init__(self, frames: LabelledFrames, cache: list[torch.Tensor], labels: dict[str, torch.Tensor]):
        n = len(labels.get("index", []))
        if cache and len(cache[0]) != n:
            raise ValueError(f"cache holds {len(cache[0])} views, the labels {n}")
        self.frames, self.cache, self.labels = frames, cache, labels

    def set_epoch(self, epoch: int) -> None:
        self.frames.set_epoch(epoch)

    def __len__(self) -> int:
        return len(self.labels.get("index", []))

    def __getitem__(self, item: int | tuple[int, int]) -> dict:
        i = item[0] if isinstance(item, tuple) else item
        return {**{f"{FEATURE_KEY}{j}": f[i].float() for j, f in enumerate(self.cache)},
                **{k: v[i] for k, v in self.labels.items()}}
