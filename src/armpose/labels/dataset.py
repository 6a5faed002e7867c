"""The labelled dataset on disk: one ``.npy`` array per field, memory-mappable, plus ``index.json``.

Layout of ``data/labels/``::

    images.npy (N, h, w, 3) uint8    masks.npy (N, h, w) uint8      joints.npy (N, J, 3) float32
    joint_valid.npy (N, J) bool      base.npy (N, 3) float32        distance.npy (N,) float32
    intrinsics.npy (N, 4) float32    frame.npy (N,) int64           robot.npy (N,) int64
    recording.npy (N,) int64         source.npy (N,) uint8          split.npy (N,) uint8 (0 train, 1 test)
    index.json                       robot types, recordings, counts, skipped problems

The folder is built beside the old one and swapped in by renames, so a reader never sees
a half-written dataset; ``index.json`` is written last.
"""
from __future__ import annotations

import json
import math
import shutil
import zlib
from pathlib import Path

import numpy as np

from armpose.io import atomic_save_npy, atomic_write_json

ARRAYS = ("images", "masks", "joints", "joint_valid", "base", "distance", "intrinsics", "frame",
          "robot", "recording", "source", "split")
SOURCE_CODES = {"synthetic": 0, "recorded": 1}


def split_for(name: str, n: int, seed: int, test_fraction: float) -> np.ndarray:
    """0/1 (train/test) per frame of synthetic recording ``name`` (``n`` frames), each frame
    test with probability ``test_fraction``, from a generator seeded by ``seed`` and the name.
    Recorded recordings are split whole, by :func:`recorded_test_names`."""
    rng = np.random.default_rng([seed, 2, zlib.crc32(name.encode())])
    return (rng.uniform(size=n) < test_fraction).astype(np.uint8)


def recorded_test_names(recordings: list[dict], seed: int, test_fraction: float) -> set[str]:
    """The names of the recorded recordings that are test data (whole recordings, never frames).

    ``recordings`` are dicts with ``name``, ``robot`` and ``static_camera`` (bool, see
    :func:`armpose.recording.static_camera`). Rule, deterministic for a given ``seed``:

    - every static-camera (tripod) recording is test: it is the use-case evaluation (pooled
      camera-to-robot pose over images of one static camera);
    - of each robot type's moving-camera recordings (n of them, sorted by name),
      ``ceil(test_fraction * n)`` are test, drawn by a generator seeded by ``seed`` and the robot
      type; so every robot type with recorded data has recorded test recordings.
    """
    test = {r["name"] for r in recordings if r["static_camera"]}
    for robot in sorted({r["robot"] for r in recordings}):
        moving = sorted(r["name"] for r in recordings if r["robot"] == robot and not r["static_camera"])
        if moving:
            rng = np.random.default_rng([seed, 3, zlib.crc32(robot.encode())])
            k = math.ceil(test_fraction * len(moving) - 1e-9)
            test.update(moving[i] for i in rng.choice(len(moving), size=k, replace=False))
    return test


def write_dataset(out: Path, parts: list[dict], index: dict) -> None:
    """Concatenate per-recording ``parts`` (dicts of arrays) into ``out`` atomically."""
    out = Path(out)
    tmp = out.with_name(f".{out.name}.tmp")
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    for name in ARRAYS:
        atomic_save_npy(tmp / f"{name}.npy", np.concatenate([p[name] for p in parts]))
    atomic_write_json(tmp / "index.json", index)
    old = out.with_name(f".{out.name}.old")
    if out.exists():
        if old.exists():
            shutil.rmtree(old)
        out.rename(old)
    tmp.rename(out)
    if old.exists():
        shutil.rmtree(old)


def load_dataset(folder: Path, mmap: bool = True) -> tuple[dict[str, np.ndarray], dict]:
    """The arrays (memory-mapped by default) and the index of a labelled dataset."""
    folder = Path(folder)
    index_path = folder / "index.json"
    if not index_path.exists():
        raise FileNotFoundError(f"{index_path}: no finished labelled dataset here (run `armpose labels`)")
    index = json.loads(index_path.read_text())
    arrays = {name: np.load(folder / f"{name}.npy", mmap_mode="r" if mmap else None) for name in ARRAYS}
    return arrays, index
