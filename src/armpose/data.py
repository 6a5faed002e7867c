"""Training data from the labelled dataset: a torch ``Dataset``, row selections and loaders.

* :class:`LabelledFrames` reads rows of ``data/labels`` (see :mod:`armpose.labels.dataset`)
  as dicts of tensors, with optional photometric augmentation.
* :func:`split_indices`, :func:`robot_indices`, :func:`transfer_set` and
  :func:`validation_subset` choose rows; all return sorted ``np.int64`` row numbers.
* :func:`make_loader` builds a seeded ``DataLoader``; :class:`InfiniteBatches` cycles its
  epochs forever and can resume at any step.

Determinism. An item depends only on (dataset row, epoch, seed): the epoch travels with the
index (the loader's sampler yields ``(position, epoch)`` pairs), so neither the worker
that loads an item nor persistent workers holding a stale copy of the dataset can change
it, and the order of an epoch is a function of (seed, epoch) alone.
"""
from __future__ import annotations

import itertools
import logging
import os
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset, Sampler
from torch.utils.data.distributed import DistributedSampler

from armpose.augment import (GEOMETRIC_KEYS, dolly_points, draw_dolly, draw_rotation, draw_zoom, draw_zoom_scale,
                             rotate_points, warp, zoom_config)
from armpose.labels.dataset import load_dataset

log = logging.getLogger(__name__)

SPLITS = {"train": 0, "test": 1}
DEFAULT_AUGMENT = {"brightness": 0.25, "contrast": 0.25, "saturation": 0.25, "noise": 0.02,
                   "flip": 0.0, "rotate_deg": 0.0, "roll_deg": 0.0, "dolly": 0.0, "zoom": None}
_GRAY = np.array([0.299, 0.587, 0.114], np.float32)


class LabelledFrames(Dataset):
    """Rows ``indices`` of the labelled dataset in ``folder``, as dicts of tensors.

    ``dataset[i]`` (``i`` a position in ``indices``; ``dataset[(i, epoch)]`` for an explicit
    epoch) gives ``image`` float32 (3, H, W) in [0, 1], ``mask`` float32 (H, W) {0, 1},
    ``joints`` float32 (J, 3) metres in the camera frame, ``joint_valid`` bool (J,), ``base``
    float32 (3,), ``robot`` int64, ``distance`` float32, ``intrinsics`` float32 (4,) fx, fy,
    cx, cy, ``image_size`` int64 (2,) width and height, and ``index`` int64 (the dataset row).

    ``augment`` (``None``: off) jitters brightness, contrast and saturation by a factor drawn
    from [1 - x, 1 + x] for each key ``x`` given, then adds Gaussian noise of a standard
    deviation drawn from [0, ``noise``]. ``flip``, ``rotate_deg`` and ``roll_deg`` add a virtual
    turn of the camera (:mod:`armpose.augment`), which warps image and mask and rotates joints
    and base so the labels stay exact; ``dolly`` then moves the camera along its axis (image
    scaled, joints, base and ``distance`` moved to match, see :mod:`armpose.augment`);
    ``zoom`` (a mapping) sometimes turns the camera to the robot and dollies in until it fills
    the frame, the view of the zoom test's second look. The draws come from a generator
    seeded by (``seed``, row, epoch); the geometric ones from a second stream and the zoom's
    from a third, so the photometric draws do not change.

    The memory-mapped arrays are opened on first use in each process and never pickled, so
    the dataset is safe in ``DataLoader`` workers started by fork or spawn.
    """

    def __init__(self, folder: Path, indices: np.ndarray | None = None, augment: dict | None = None,
                 seed: int = 0):
        self.folder = Path(folder)
        arrays, self.meta = load_dataset(self.folder)
        n = len(arrays["split"])
        self.indices = np.arange(n, dtype=np.int64) if indices is None else np.asarray(indices, np.int64)
        if self.indices.ndim != 1 or (self.indices.size and (self.indices.min() < 0 or self.indices.max() >= n)):
            raise ValueError(f"indices must be a 1-D array of rows in [0, {n}) of {self.folder}")
        unknown = set(augment or {}) - set(DEFAULT_AUGMENT)
        if unknown:
            raise ValueError(f"unknown augmentation keys {sorted(unknown)}; known: {sorted(DEFAULT_AUGMENT)}")
        self.augment = dict(augment) if augment else None
        zoom_config(self.augment or {})   # a bad zoom setting fails here, naming the value
        self.seed = int(seed)
        self.epoch = 0
        self._arrays, self._pid = arrays, os.getpid()

    @property
    def robot_types(self) -> list[str]:
        return list(self.meta["robot_types"])

    @property
    def arrays(self) -> dict[str, np.ndarray]:
        """The memory-mapped arrays, opened once per process."""
        if self._arrays is None or self._pid != os.getpid():
            self._arrays, _ = load_dataset(self.folder)
            self._pid = os.getpid()
        return self._arrays

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_arrays": None, "_pid": None}

    def set_epoch(self, epoch: int) -> None:
        """The epoch used by ``dataset[i]``; loaders from :func:`make_loader` pass it with the index."""
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, item: int | tuple[int, int]) -> dict[str, torch.Tensor]:
        i, epoch = item if isinstance(item, tuple) else (item, self.epoch)
        row = int(self.indices[i])
        a = self.arrays
        image = np.asarray(a["images"][row])
        mask = np.asarray(a["masks"][row]) > 0
        joints = np.array(a["joints"][row], np.float32)
        base = np.array(a["base"][row], np.float32)
        intrinsics = np.array(a["intrinsics"][row], np.float32)
        valid = np.array(a["joint_valid"][row], bool)
        distance = float(a["distance"][row])
        if self.augment and any(self.augment.get(k) for k in GEOMETRIC_KEYS):
            joints, base, image, mask, distance = self._moved(row, epoch, joints, base, image, mask, intrinsics,
                                                              valid, distance)
        if self.augment:
            img = self._augmented(image, row, int(epoch))
        else:
            img = torch.from_numpy(np.ascontiguousarray(image.transpose(2, 0, 1))).float().div_(255)
        return {
            "image": img,
            "mask": torch.from_numpy(mask).float(),
            "joints": torch.from_numpy(joints),
            "joint_valid": torch.from_numpy(valid),
            "base": torch.from_numpy(base),
            "robot": torch.tensor(int(a["robot"][row]), dtype=torch.int64),
            "distance": torch.tensor(distance, dtype=torch.float32),
            "intrinsics": torch.from_numpy(intrinsics),
            "image_size": torch.tensor([image.shape[1], image.shape[0]], dtype=torch.int64),
            "index": torch.tensor(row, dtype=torch.int64),
        }

    def _moved(self, row: int, epoch: int, joints, base, image, mask, intrinsics, valid, distance):
        """Labels and pixels after the virtual camera turn and dolly drawn for (row, epoch):
        ``(joints, base, image, mask, distance)``, the mask as bool."""
        rng = np.random.default_rng([self.seed, row, epoch, 1])
        size = (image.shape[1], image.shape[0])
        points = np.vstack([base[None], joints[valid]])
        zoom = draw_zoom(np.random.default_rng([self.seed, row, epoch, 2]), self.augment, points, intrinsics, size)
        M = draw_rotation(rng, self.augment, intrinsics, image.shape[1], pan_tilt=zoom is None)
        scale = draw_dolly(rng, self.augment)
        M = np.eye(3) if M is None else M
        if zoom is not None:
            M = M @ zoom[0]
            scale = draw_zoom_scale(np.random.default_rng([self.seed, row, epoch, 3]), zoom[1],
                                    rotate_points(points, M), intrinsics, size, float(self.augment.get("dolly", 0.0)))
        image, mask = warp(image, mask.astype(np.uint8), M, intrinsics, 1.0 if scale is None else scale)
        joints, base = rotate_points(joints, M), rotate_points(base, M)
        if scale is not None:
            z_ref = float(joints[valid, 2].mean()) if valid.any() else float(base[2])
            joints, base = dolly_points(joints, scale, z_ref), dolly_points(base, scale, z_ref)
            distance /= scale   # camera-to-robot distance, to first order
        return joints.astype(np.float32), base.astype(np.float32), image, mask > 0, distance

    def _augmented(self, image: np.ndarray, row: int, epoch: int) -> torch.Tensor:
        """Photometric jitter of one uint8 HWC image, as float32 CHW in [0, 1].

        Brightness ``b``, contrast ``c`` (about the mean grey level) and saturation ``s``
        (about each pixel's grey level) compose to one affine map
        ``x' = s*c*b*x + (1-s)*c*b*gray(x) + (1-c)*b*mean(gray(x))``, applied in one pass.
        The noise is a window of a standard-normal bank (fixed seed, twice the image size,
        built once per process) at an offset drawn with the other factors, scaled by sigma:
        as random as fresh noise for training, at a fraction of the cost.
        """
        aug = self.augment
        rng = np.random.default_rng([self.seed, row, epoch])
        x = image.transpose(2, 0, 1).astype(np.float32)

        def factor(key: str) -> float:
            s = float(aug.get(key, 0.0))
            return float(rng.uniform(1 - s, 1 + s))

        b, c, s = factor("brightness"), factor("contrast"), factor("saturation")
        sigma = float(rng.uniform(0, float(aug.get("noise", 0.0))))
        dy, dx = (int(v) for v in rng.integers(0, (x.shape[1], x.shape[2])))
        gray = np.tensordot(_GRAY / np.float32(255), x, axes=1)
        x *= np.float32(s * c * b / 255)
        x += np.float32((1 - s) * c * b) * gray + np.float32((1 - c) * b * gray.mean())
        if sigma > 0:
            bank = _noise_bank(x.shape[1], x.shape[2])
            x += np.float32(sigma) * bank[:, dy:dy + x.shape[1], dx:dx + x.shape[2]]
        np.clip(x, 0.0, 1.0, out=x)
        return torch.from_numpy(x)


_NOISE_BANKS: dict[tuple[int, int], np.ndarray] = {}


def _noise_bank(h: int, w: int) -> np.ndarray:
    """``(3, 2h, 2w)`` float32 standard normal, the same in every process (seed 0)."""
    if (h, w) not in _NOISE_BANKS:
        _NOISE_BANKS[(h, w)] = np.random.default_rng(0).standard_normal((3, 2 * h, 2 * w), dtype=np.float32)
    return _NOISE_BANKS[(h, w)]


# --- row selections ---------------------------------------------------------------------

def _arrays_of(source) -> dict[str, np.ndarray]:
    """The arrays of a dataset folder, a ``load_dataset`` result, a dict or a LabelledFrames."""
    if isinstance(source, LabelledFrames):
        return source.arrays
    if isinstance(source, (str, Path)):
        return load_dataset(Path(source))[0]
    if isinstance(source, tuple):
        return source[0]
    return source


def _split_code(split: str | int) -> int:
    if isinstance(split, str):
        if split not in SPLITS:
            raise ValueError(f"split must be one of {list(SPLITS)}, not {split!r}")
        return SPLITS[split]
    return int(split)


def split_indices(index_or_arrays, split: str) -> np.ndarray:
    """Rows of ``split`` ("train": split == 0, "test": split == 1).

    ``index_or_arrays``: a dataset folder, ``load_dataset``'s (arrays, index), the arrays dict,
    a :class:`LabelledFrames`, or the ``split`` column itself.
    """
    column = index_or_arrays if isinstance(index_or_arrays, np.ndarray) else _arrays_of(index_or_arrays)["split"]
    return np.flatnonzero(np.asarray(column) == _split_code(split)).astype(np.int64)


def robot_indices(arrays, robots: Sequence[int]) -> np.ndarray:
    """Rows whose robot class index is in ``robots``."""
    robot = np.asarray(_arrays_of(arrays)["robot"])
    return np.flatnonzero(np.isin(robot, np.asarray(list(robots), np.int64))).astype(np.int64)


def robot_classes(index: dict, names: Sequence[str]) -> list[int]:
    """Class indices of robot type ``names`` in a dataset's ``index.json``."""
    types = list(index["robot_types"])
    missing = [n for n in names if n not in types]
    if missing:
        raise ValueError(f"robot types {missing} are not in the dataset's {types}")
    return [types.index(n) for n in names]


def _per_type(arrays, split: str, robots: Sequence[int] | None, count: int | None, seed: int,
              warn: bool) -> np.ndarray:
    """Up to ``count`` (``None``: all) rows of ``split`` per robot class, drawn without replacement.

    Each class draws from its own generator seeded by (seed, class), so adding a class
    leaves the others' rows unchanged.
    """
    a = _arrays_of(arrays)
    robot = np.asarray(a["robot"])
    in_split = np.asarray(a["split"]) == _split_code(split)
    robots = sorted(set(np.unique(robot[in_split]).tolist())) if robots is None else list(robots)
    chosen = []
    for r in robots:
        rows = np.flatnonzero(in_split & (robot == r))
        if count is None or len(rows) <= count:
            if warn and len(rows) < count:
                log.warning("robot class %d: only %d %s frames, fewer than the %d asked for; using all of them",
                            r, len(rows), split, count)
            chosen.append(rows)
        else:
            rng = np.random.default_rng([int(seed), int(r)])
            chosen.append(rng.choice(rows, size=count, replace=False))
    return np.sort(np.concatenate(chosen)).astype(np.int64) if chosen else np.zeros(0, np.int64)


def foreground_fraction(arrays, rows: np.ndarray, max_rows: int = 1000) -> float:
    """Mean fraction of robot pixels in the masks of ``rows`` (at most ``max_rows`` of them,
    evenly spaced, so the answer is deterministic and cheap); 0.5 for no rows."""
    rows = np.asarray(rows, np.int64)
    if not len(rows):
        return 0.5
    pick = rows[np.linspace(0, len(rows) - 1, min(len(rows), max_rows)).round().astype(np.int64)]
    masks = _arrays_of(arrays)["masks"]
    return float(np.mean([np.count_nonzero(masks[r]) / masks[r].size for r in pick]))


def transfer_set(arrays, split: str = "train", robots: Sequence[int] | None = None,
                 per_type: int | None = None, seed: int = 0) -> np.ndarray:
    """The paper's transfer set: ``per_type`` rows of ``split`` per robot class in ``robots``
    (default: every class present), sampled without replacement; all of them, with a warning,
    where fewer exist. ``per_type=None`` takes every row of those classes, without warning."""
    if per_type is None:
        return _per_type(arrays, split, robots, None, seed, warn=False)
    return _per_type(arrays, split, robots, int(per_type), seed, warn=True)


def validation_subset(arrays, split: str = "test", max_per_type: int | None = None, seed: int = 0,
                      robots: Sequence[int] | None = None) -> np.ndarray:
    """At most ``max_per_type`` rows of ``split`` per robot class in ``robots`` (default:
    every class present; ``max_per_type=None``: no cap), for quick validation in training."""
    return _per_type(arrays, split, robots, None if max_per_type is None else int(max_per_type), seed,
                     warn=False)


# --- loaders ----------------------------------------------------------------------------

class SeededSampler(Sampler[int]):
    """Positions 0..n-1, shuffled by a permutation that depends only on (seed, epoch)."""

    def __init__(self, n: int, shuffle: bool, seed: int):
        self.n, self.shuffle, self.seed, self.epoch = int(n), bool(shuffle), int(seed), 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return self.n

    def __iter__(self) -> Iterator[int]:
        if not self.shuffle:
            return iter(range(self.n))
        g = torch.Generator().manual_seed(self.seed + self.epoch)
        return iter(torch.randperm(self.n, generator=g).tolist())


class EpochSampler(Sampler[tuple[int, int]]):
    """Wraps a sampler with ``set_epoch`` and yields ``(position, epoch)`` pairs.

    Carrying the epoch with each index keeps augmentation right in persistent workers, whose
    copy of the dataset never sees ``set_epoch`` calls made in the main process. With
    ``tag=False`` it yields plain positions (for datasets that take only ints).
    :meth:`skip` drops the first ``n`` indices of the next pass only (for resuming).
    """

    def __init__(self, sampler: Sampler[int], tag: bool = True):
        self.sampler, self.tag, self.epoch, self._skip = sampler, bool(tag), 0, 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)
        self.sampler.set_epoch(self.epoch)

    def skip(self, n: int) -> None:
        self._skip = int(n)

    def __len__(self) -> int:
        return len(self.sampler)

    def __iter__(self) -> Iterator[tuple[int, int] | int]:
        skip, self._skip, epoch = self._skip, 0, self.epoch
        rest = itertools.islice(iter(self.sampler), skip, None)
        return ((int(i), epoch) for i in rest) if self.tag else (int(i) for i in rest)


def make_loader(dataset: Dataset, batch_size: int, shuffle: bool, seed: int, num_workers: int,
                drop_last: bool, distributed: bool = False, prefetch_factor: int = 4,
                multiprocessing_context: str | None = None) -> DataLoader:
    """A seeded ``DataLoader`` whose batches depend only on (seed, epoch), not on the workers.

    The epoch order comes from a generator seeded by ``seed + epoch``; with ``distributed``
    it is a ``DistributedSampler(dataset, shuffle=shuffle, seed=seed, drop_last=drop_last)``
    (the process group must be initialised). Either way ``loader.sampler`` is an
    :class:`EpochSampler` (passing the epoch with each index to datasets with ``set_epoch``,
    such as :class:`LabelledFrames`), and **the caller must call**
    ``loader.sampler.set_epoch(epoch)`` before each epoch (:class:`InfiniteBatches` does), or
    every epoch repeats epoch 0's order and augmentation. Workers persist across epochs and prefetch ``prefetch_factor``
    batches each, so loading overlaps compute; memory is pinned only when CUDA is available.
    """
    inner = (DistributedSampler(dataset, shuffle=shuffle, seed=seed, drop_last=drop_last) if distributed
             else SeededSampler(len(dataset), shuffle, seed))
    sampler, workers = EpochSampler(inner, tag=hasattr(dataset, "set_epoch")), int(num_workers)
    return DataLoader(dataset, batch_size=batch_size, sampler=sampler, drop_last=drop_last,
                      num_workers=workers, generator=torch.Generator().manual_seed(int(seed)),
                      persistent_workers=workers > 0, pin_memory=torch.cuda.is_available(),
                      prefetch_factor=prefetch_factor if workers > 0 else None,
                      multiprocessing_context=multiprocessing_context if workers > 0 else None)


class InfiniteBatches:
    """Batches of a :func:`make_loader` loader forever: ``batch = next(batches)``.

    After each ``next``, ``batches.epoch`` is the epoch of the batch just returned and
    ``batches.step`` the global step of the next one (it starts at ``start_step``).

    Step ``s`` is batch ``s % B`` of epoch ``s // B``, with ``B = len(loader)`` batches per
    epoch, and every epoch's order and augmentation depend only on (seed, epoch). Resuming
    at ``start_step`` therefore needs no replay: it sets the epoch to ``start_step // B`` and
    tells the sampler to drop its first ``(start_step % B) * batch_size`` indices, which
    costs one permutation and loads no images. Batches are consecutive chunks of the
    sampler's order, so the remaining batches are exactly those of an uninterrupted run.
    """

    def __init__(self, loader: DataLoader, start_step: int = 0):
        if not isinstance(loader.sampler, EpochSampler):
            raise TypeError("InfiniteBatches needs a loader from armpose.data.make_loader")
        self.loader = loader
        self.batches_per_epoch = len(loader)
        if self.batches_per_epoch == 0:
            raise ValueError("the loader yields no batches (dataset smaller than one batch with drop_last?)")
        self.step = int(start_step)
        self.epoch = self.step // self.batches_per_epoch
        self._iter: Iterator | None = None

    def __iter__(self) -> "InfiniteBatches":
        return self

    def __next__(self) -> dict:
        while True:
            if self._iter is None:
                epoch, offset = divmod(self.step, self.batches_per_epoch)
                self.loader.sampler.set_epoch(epoch)
                if hasattr(self.loader.dataset, "set_epoch"):
                    self.loader.dataset.set_epoch(epoch)
                self.loader.sampler.skip(offset * self.loader.batch_size)
                self._iter = iter(self.loader)
            try:
                batch = next(self._iter)
            except StopIteration:
                self._iter = None
                continue
            self.epoch, self.step = self.step // self.batches_per_epoch, self.step + 1
            return batch
