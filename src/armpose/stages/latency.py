"""Stage ``latency``: forward time per frame of the trained network (paper: 19-23 ms, GTX 1080 Ti).

Batch 1: the median and 95th percentile over ``frames`` timed forwards after ``warmup``
untimed ones; batch ``batch``: frames per second; with ``mirror_test``, also batch 1 with
the mirror test (``armpose predict --mirror``: each image with its mirror, one forward);
with ``zoom_test``, batch 1 with the zoom test (``armpose predict --zoom``: two forwards,
the second on the view of a camera turned to the robot and moved closer, settings from the
checkpoint); with ``kinematic_fit``, batch 1 with the zoom test (when on) and the kinematic fit
(``armpose predict --zoom --fit``, :mod:`armpose.kinematic_fit`); with ``zoom_on_mirror`` as
well, those two run on mirror-averaged passes (``armpose predict --mirror --zoom [--fit]``, as
the ``evaluate`` stage scores them with its ``zoom_on_mirror``). On CPU with ``threads`` torch threads,
and on CUDA as well when a GPU is present. Inputs are test images from ``data/labels`` at
the network's 256x212 input. Writes ``results/latency.json``; ``benchmarks/bench_inference.py``
is the same function from the command line.
"""
from __future__ import annotations

import argparse
import logging
import os
import platform
import time
from pathlib import Path

import numpy as np
import torch

from armpose.config import load_params, project_root
from armpose.data import LabelledFrames, split_indices
from armpose.inference import load_inference_model
from armpose.io import atomic_write_json
from armpose.labels.dataset import load_dataset
from armpose.mirror_test import MirrorAveraged, forward_with_mirror
from armpose.robots import get_robot
from armpose.fit_sigmas import checkpoint_fit_sigmas
from armpose.kinematic_fit import fit_predictions
from armpose.zoom_test import forward_with_zoom, settings_from_config

log = logging.getLogger(__name__)
OUTPUT = Path("results/latency.json")


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _batch1_times(forward, imgs: torch.Tensor, device: torch.device, frames: int, warmup: int) -> list[float]:
    """Milliseconds of ``forward`` on each of ``frames`` single images, after ``warmup`` untimed calls."""
    for i in range(warmup):
        forward(imgs[i % len(imgs)][None])
    _sync(device)
    times = []
    for i in range(frames):
        t = time.perf_counter()
        forward(imgs[i % len(imgs)][None])
        _sync(device)
        times.append(1000 * (time.perf_counter() - t))
    return times


@torch.no_grad()
def time_device(model, images: torch.Tensor, device: torch.device, frames: int, warmup: int, batch: int,
                mirror_camera: tuple[float, float] | None = None,
                zoom_camera: tuple[float, float, float, float] | None = None, zoom_settings: dict | None = None,
                joint_counts: list[int] | None = None, fit_types: list[str] | None = None,
                fit_sigmas: dict | None = None, zoom_on_mirror: bool = False) -> dict:
    """Batch-1 latency (ms) and batch-``batch`` throughput (frames/s) of ``model`` on ``device``;
    with ``mirror_camera`` (the network camera's fx, cx in pixels), also the batch-1 latency of
    the mirror test (:func:`armpose.mirror_test.forward_with_mirror`, two images a forward);
    with ``zoom_camera`` (fx, fy, cx, cy), that of the zoom test
    (:func:`armpose.zoom_test.forward_with_zoom` with ``zoom_settings``, two forwards and the
    resampling; ``joint_counts``
    per robot type, as ``armpose predict`` passes them); with ``fit_types`` (the robot types by class
    index), that of the zoom test (or the single pass) followed by the kinematic fit of the predicted type.
    With ``zoom_on_mirror`` (needs ``mirror_camera``), the zoom test's two looks and the single pass
    before the fit are mirror-averaged (:class:`armpose.mirror_test.MirrorAveraged`), as in
    ``armpose predict --mirror --zoom --fit``."""
    if zoom_on_mirror and mirror_camera is None:
        raise ValueError("latency.zoom_on_mirror times the zoom test on the mirror test's passes: it needs mirror_test")
    model = model.to(device)
    looked = MirrorAveraged(model, *mirror_camera) if zoom_on_mirror else model
    imgs = images.to(device).contiguous(memory_format=torch.channels_last)
    times = _batch1_times(model, imgs, device, frames, warmup)
    big = imgs[np.arange(batch) % len(imgs)]
    model(big)
    _sync(device)
    t = time.perf_counter()
    reps = 3
    for _ in range(reps):
        model(big)
    _sync(device)
    fps = reps * batch / (time.perf_counter() - t)
    out = {"batch1_median_ms": round(float(np.median(times)), 3), "batch1_p95_ms": round(float(np.percentile(times, 95)), 3),
           "batch1_frames": frames, f"batch{batch}_fps": round(fps, 2)}
    if mirror_camera is not None:
        mirrored = _batch1_times(lambda x: forward_with_mirror(model, x, *mirror_camera), imgs, device, frames, warmup)
        out.update(mirror_batch1_median_ms=round(float(np.median(mirrored)), 3),
                   mirror_batch1_p95_ms=round(float(np.percentile(mirrored, 95)), 3))
    if zoom_camera is not None:
        zoomed = _batch1_times(lambda x: forward_with_zoom(looked, x, zoom_camera, zoom_settings, joint_counts),
                               imgs, device, frames, warmup)
        out.update(zoom_batch1_median_ms=round(float(np.median(zoomed)), 3),
                   zoom_batch1_p95_ms=round(float(np.percentile(zoomed, 95)), 3))
    if fit_types is not None:
        def fitted(x):
            out = forward_with_zoom(looked, x, zoom_camera, zoom_settings, joint_counts)[1] if zoom_camera else looked(x)
            types = out["type_logits"].argmax(-1).cpu().numpy()
            return fit_predictions(out["joints"].double().cpu().numpy(), out["base"].double().cpu().numpy(), types,
                                   fit_types, sigmas=fit_sigmas)
        times = _batch1_times(fitted, imgs, device, frames, warmup)
        out.update(fit_batch1_median_ms=round(float(np.median(times)), 3),
                   fit_batch1_p95_ms=round(float(np.percentile(times, 95)), 3))
    return out


def run(params: dict, root: Path | None = None) -> dict:
    """Time the stage-2 checkpoint; returns and writes the results dict."""
    root = Path(root or project_root())
    cfg = params["latency"]
    torch.set_num_threads(int(cfg["threads"]))
    model, config = load_inference_model(root / cfg["checkpoint"])
    counts = [get_robot(t).num_joints for t in config["base"]["robot_types"]]
    data = root / "data" / "labels"
    arrays, _ = load_dataset(data)
    rows = split_indices(arrays, "test")[: int(cfg["images"])]
    frames = LabelledFrames(data, rows)
    images = torch.stack([frames[i]["image"] for i in range(len(frames))])
    fx, fy, cx, cy = (float(v) for v in frames[0]["intrinsics"])
    mirror = (fx, cx) if cfg.get("mirror_test", False) else None
    zoom = (fx, fy, cx, cy) if cfg.get("zoom_test", False) else None
    fit_types = list(config["base"]["robot_types"]) if cfg.get("kinematic_fit", False) else None
    options = (mirror, zoom, settings_from_config(config), counts, fit_types,
               checkpoint_fit_sigmas(root / cfg["checkpoint"]) if fit_types else None,
               bool(cfg.get("zoom_on_mirror", False)))
    result = {"checkpoint": cfg["checkpoint"], "input": f"{images.shape[-1]}x{images.shape[-2]}",
              "paper_ms": [19, 23], "paper_device": "GTX 1080 Ti", "target_cpu_median_ms": 15.0,
              "zoom_on_mirror": bool(cfg.get("zoom_on_mirror", False)),
              "cpu": {"threads": int(cfg["threads"]), "processor": platform.processor() or platform.machine(),
                      "cpu_count": os.cpu_count(),
                      **time_device(model, images, torch.device("cpu"), int(cfg["frames"]), int(cfg["warmup"]),
                                    int(cfg["batch"]), *options)}}
    if torch.cuda.is_available():
        result["cuda"] = {"device": torch.cuda.get_device_name(0),
                          **time_device(model, images, torch.device("cuda"), int(cfg["frames"]), int(cfg["warmup"]),
                                        int(cfg["batch"]), *options)}
    atomic_write_json(root / OUTPUT, result)
    return result


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="armpose latency", description=__doc__)
    ap.add_argument("--params", default=None, help="params file (default: the project's params.yaml)")
    ap.add_argument("--root", default=None, help="project root holding data/ and models/")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    res = run(load_params(args.params), args.root)
    for dev in ("cpu", "cuda"):
        if dev in res:
            r = res[dev]
            fps = {k: v for k, v in r.items() if k.endswith("_fps")}
            mirror = "".join(f"; {k} test, batch 1: median {r[f'{k}_batch1_median_ms']:.1f} ms"
                             for k in ("mirror", "zoom", "fit") if f"{k}_batch1_median_ms" in r)
            print(f"latency {dev}: batch 1 median {r['batch1_median_ms']:.1f} ms, p95 {r['batch1_p95_ms']:.1f} ms; "
                  + ", ".join(f"{k[:-4]} {v:.0f} frames/s" for k, v in fps.items()) + mirror)
    print(f"latency: wrote {Path(args.root or project_root()) / OUTPUT}")


if __name__ == "__main__":
    main()
