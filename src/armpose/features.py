"""Frozen-trunk feature cache: how a run that trains the heads only (transfer stage 1) is cheap.

When every trainable group sits after the trunk and the mask decoder is frozen too, the
trunk's output for a frame never changes during the run (its BatchNorm layers are in eval
mode). :func:`cache_trunk_features` runs the trunk once over the training frames, without
augmentation, and :class:`CachedFeatureFrames` serves them (``feat0``, ``feat1``, ...: what
:meth:`armpose.model.ArmPoseNet.trunk_features` gives, ``[c2, c3, c4]``, or ``[c1, c2, c3, c4]``
with stride-4 keypoint heads) with the labels, so a step is the heads' forward and backward
only; :func:`batch_features` turns a batch back into the list the model takes. The mask term drops out (its branch is frozen);
validation still runs the whole network on images.

The cache lives in memory as float16: c2, c3 and c4 are about 98,000 values per frame at
width 32 and 256x212 (196 kB), 490 MB for the 2,500 frames of the default transfer set;
stride-4 keypoint heads add c1 and double that.
"""
from __future__ import annotations

import logging

import numpy as np
import torch
from torch.utils.data import Dataset
from tqdm import tqdm

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


@torch.no_grad()
def cache_trunk_features(model, frames: LabelledFrames, device, batch_size: int = 32,
                         disable_bar: bool = False) -> list[torch.Tensor]:
    """``[c2, c3, c4]`` for every frame of ``frames`` (read without augmentation), in its
    order, as CPU :data:`CACHE_DTYPE` tensors ``(N, C, h, w)``. ``model`` is an unwrapped :class:`ArmPoseNet`."""
    plain = LabelledFrames(frames.folder, frames.indices)
    was_training = model.training
    model.eval()
    parts: list[list[torch.Tensor]] = []
    for start in tqdm(range(0, len(plain), batch_size), desc="caching trunk features", unit="batch",
                      disable=disable_bar, dynamic_ncols=True):
        images = torch.stack([plain[i]["image"] for i in range(start, min(start + batch_size, len(plain)))])
        images = images.to(device).contiguous(memory_format=torch.channels_last)
        parts.append([f.to(CACHE_DTYPE).cpu().contiguous() for f in model.trunk_features(images)])
    model.train(was_training)
    if not parts:
        return []
    feats = [torch.cat([p[i] for p in parts]) for i in range(len(parts[0]))]
    log.info("cached trunk features of %d frames: %.0f MB", len(plain),
             sum(f.numel() * f.element_size() for f in feats) / 1e6)
    return feats


class CachedFeatureFrames(Dataset):
    """The items of ``frames`` without ``image`` and ``mask``, plus ``c2``, ``c3``, ``c4``
    from ``cache`` (same order as ``frames``). Works with :func:`armpose.data.make_loader`."""

    def __init__(self, frames: LabelledFrames, cache: list[torch.Tensor]):
        if cache and len(cache[0]) != len(frames):
            raise ValueError(f"cache holds {len(cache[0])} frames, the dataset {len(frames)}")
        self.frames, self.cache = frames, cache

    def set_epoch(self, epoch: int) -> None:
        self.frames.set_epoch(epoch)

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, item: int | tuple[int, int]) -> dict:
        i = item[0] if isinstance(item, tuple) else item
        a = self.frames.arrays
        row = int(self.frames.indices[i])
        return {
            **{f"{FEATURE_KEY}{j}": f[i].float() for j, f in enumerate(self.cache)},
            "joints": torch.from_numpy(np.array(a["joints"][row], np.float32)),
            "joint_valid": torch.from_numpy(np.array(a["joint_valid"][row], bool)),
            "base": torch.from_numpy(np.array(a["base"][row], np.float32)),
            "robot": torch.tensor(int(a["robot"][row]), dtype=torch.int64),
            "intrinsics": torch.from_numpy(np.array(a["intrinsics"][row], np.float32)),
            "image_size": torch.tensor(a["images"].shape[2:0:-1], dtype=torch.int64),
            "index": torch.tensor(row, dtype=torch.int64),
        }
