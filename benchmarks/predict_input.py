"""Does ``armpose predict`` show the network a frame as the label stage made its training inputs?

    python benchmarks/predict_input.py [--frames 300] [--out results/predict_input.json]

For ``--frames`` test frames of ``data/labels`` drawn with the ``base.seed`` of ``params.yaml``,
reads each frame's raw image from its recording (the canonical 480x360 camera), warps it into the
network camera as ``armpose predict`` does (:func:`armpose.predict.to_network`) and compares the
result with the stored label image (:func:`armpose.labels.compute.scale_crop_image`), in grey
levels (0-255). Identical inputs mean that ``armpose predict`` on the canonical camera gives the
network's outputs that the evaluation scores. Prints the JSON; writes it to ``--out`` if given.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from armpose.config import load_params, project_root
from armpose.io import atomic_write_json
from armpose.labels.dataset import load_dataset
from armpose.predict import network_camera, to_network, warp_for
from armpose.recording import read_frame, read_meta


def compare(root: Path, frames: int, seed: int) -> dict:
    """Mean and max absolute difference (grey levels) between predict's input and the label image."""
    base = load_params(root / "params.yaml")["base"]
    arrays, index = load_dataset(root / "data" / "labels")
    net = network_camera(base)
    test = np.flatnonzero(np.asarray(arrays["split"]) == 1)
    pick = np.sort(np.random.default_rng(seed).choice(test, min(frames, len(test)), replace=False))
    diffs = []
    for i in pick:
        rec = root / index["recordings"][int(arrays["recording"][i])]["name"]
        meta, _ = read_meta(rec)
        raw = read_frame(rec, int(arrays["frame"][i]), meta.camera)
        seen = to_network(raw, warp_for(meta.camera, net), net).astype(np.int16)
        d = np.abs(seen - np.asarray(arrays["images"][i]).astype(np.int16))
        diffs.append((float(d.mean()), int(d.max())))
    d = np.array(diffs)
    return {"frames": len(d), "mean_abs_grey_levels": round(float(d[:, 0].mean()), 4),
            "max_abs_grey_levels": int(d[:, 1].max()), "frames_identical": int((d[:, 1] == 0).sum())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    root = project_root()
    result = compare(root, args.frames, int(load_params(root / "params.yaml")["base"]["seed"]))
    if args.out:
        atomic_write_json(args.out, result)
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
