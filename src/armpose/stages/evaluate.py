"""Stage ``evaluate``: the paper's Table II and figures, regenerated from the trained models.

Evaluates the two-stage transfer model and the full-training model on the held-out test
split, per family, type and data source (synthetic test frames, recorded test recordings;
:mod:`armpose.evaluate`), the camera-to-robot pose from one image and pooled over images of a
static camera (:mod:`armpose.pose_eval`), and raw against filtered sequence metrics on the
recorded test recordings (:mod:`armpose.sequence_eval`), and writes:

- ``results/metrics.json``: hierarchical metrics (DVC metrics), plus latency and timing;
- ``results/results_table.md``: the paper's Table II side by side with ours;
- ``results/plots/*.csv``: the data behind each figure (DVC plots);
- ``results/figures/*.png``: (a) transfer-set sweep, (b) loss over the stages, (c) error
  against camera distance, (d) example test images, (e) transfer against full training,
  (f) latency;
- ``results/env.json``: git hash, machine, package versions, profile.
"""
from __future__ import annotations

import argparse
import csv
import io
import json
import logging
from pathlib import Path

import numpy as np
import torch

from armpose.config import load_params, project_root
from armpose.evaluate import evaluate_checkpoint, family_of, pixel_scale_of
from armpose.inference import load_inference_model
from armpose.io import atomic_write_bytes, atomic_write_json, atomic_write_text
from armpose.kinematic_fit import FitSettings
from armpose.metrics import error_by_distance, joint_errors, project
from armpose.model import predicted_mask
from armpose.report import environment, results_table
from armpose.train import load_checkpoint
from armpose import viz_eval
from armpose.viz import chw_to_uint8

log = logging.getLogger(__name__)
RESULTS = Path("results")


def write_csv(path: Path, rows: list[dict]) -> None:
    buf = io.StringIO()
    if rows:
        writer = csv.DictWriter(buf, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    atomic_write_bytes(path, buf.getvalue().encode())


def save_figure(fig, path: Path) -> None:
    """PNG, written atomically (temporary name, then rename)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.tmp.png")
    fig.savefig(tmp, dpi=110)
    tmp.replace(path)
    import matplotlib.pyplot as plt
    plt.close(fig)


def read_csv(path: Path) -> list[dict]:
    return list(csv.DictReader(open(path))) if path.exists() else []


def distance_rows(pred: dict, truth: dict, robot_types: list[str], edges: np.ndarray) -> list[dict]:
    """Fig. 6c data: median joint error per camera-distance bin and family."""
    err = joint_errors(pred["joints"], truth["joints"], truth["joint_valid"])
    fams = np.array(family_of(robot_types))[truth["type"]]
    rows = []
    for fam in dict.fromkeys(family_of(robot_types)):
        sel = fams == fam
        rows += [{"family": fam, **r} for r in error_by_distance(err[sel], truth["distance"][sel], edges)]
    return rows


def example_columns(checkpoint: Path, data_dir: Path, pred: dict, truth: dict, robot_types: list[str],
                    seed: int) -> list[dict]:
    """Fig. 5 data: one test frame per family (seeded draw), with the model's mask."""
    from armpose.data import LabelledFrames
    rng = np.random.default_rng(seed)
    fams = np.array(family_of(robot_types))[truth["type"]]
    model, _ = load_inference_model(checkpoint)
    cols = []
    for fam in dict.fromkeys(family_of(robot_types)):
        idx = np.flatnonzero(fams == fam)
        if not idx.size:
            continue
        i = int(rng.choice(idx))
        item = LabelledFrames(data_dir, truth["row"][i:i + 1])[0]
        with torch.no_grad():
            logits = model(item["image"][None].contiguous(memory_format=torch.channels_last))["mask_logits"]
            mask = predicted_mask(model, logits[0, 0]).numpy()
        k = truth["intrinsics"][i:i + 1]
        valid = truth["joint_valid"][i]
        cols.append({"image": chw_to_uint8(item["image"].numpy()),
                     "pred_uv": project(pred["joints"][i:i + 1], k)[0][valid],
                     "true_uv": project(truth["joints"][i:i + 1], k)[0][valid], "mask": mask,
                     "pred_base_uv": project(pred["base"][i:i + 1, None], k)[0, 0],
                     "true_base_uv": project(truth["base"][i:i + 1, None], k)[0, 0],
                     "title": f"{fam}: {robot_types[truth['type'][i]]} (predicted {robot_types[pred['type'][i]]})"})
    return cols


def training_minutes(root: Path, stages: list[str]) -> float:
    total = 0.0
    for s in stages:
        path = root / "models" / s / "summary.json"
        if path.exists():
            summary = json.loads(path.read_text())
            total += float(summary["wall_s"]) + float(summary.get("feature_cache_s", 0.0))
    return total / 60


def recorded_metrics(pred_truth: tuple[dict, dict], data_dir: Path, root: Path, params: dict,
                     camera_pose: bool) -> dict:
    """Camera-to-robot pose per family (single images on the synthetic test set; single and pooled
    images on the static-camera test recordings; :mod:`armpose.pose_eval`; ``evaluate.pose_fit``
    rays: also the rigid fit alone, under ``rigid``), if ``camera_pose``,
    raw against filtered sequence metrics on the recorded test recordings (:mod:`armpose.sequence_eval`),
    and the single pass's metrics per recorded test recording (:func:`armpose.sequence_eval.metrics_by_recording`)."""
    from armpose.labels.dataset import load_dataset
    from armpose.pose_eval import camera_pose_metrics
    from armpose.sequence_eval import metrics_by_recording, sequence_metrics
    pred, truth = pred_truth
    arrays, index = load_dataset(data_dir)
    cfg, families = params["evaluate"], family_of(list(params["base"]["robot_types"]))
    out = {"sequence": sequence_metrics(pred, truth, index, arrays, families, float(params["record"]["fps"]),
                                        list(cfg.get("sequence_filters", ["kalman"]))),
           "by_recording": metrics_by_recording(pred, truth, index, arrays, pixel_scale_of(params["base"], truth))}
    fit = cfg.get("pose_fit", "rigid")
    if fit not in ("rigid", "rays"):
        raise ValueError(f"evaluate.pose_fit must be 'rigid' or 'rays', got {fit!r}")
    if camera_pose:
        images = int(cfg.get("pose_pool_images", 10))
        out["camera_pose"] = camera_pose_metrics(pred, truth, index, arrays, root, families, images, rays=fit == "rays")
        if fit == "rays":   # the rigid fit alone, for comparison
            out["camera_pose"]["rigid"] = camera_pose_metrics(pred, truth, index, arrays, root, families, images)
    return out


TRAINING_STAGES = ("pretrain", "transfer_stage1", "transfer_stage2", "train_full")


def training_timing(root: Path) -> dict:
    """Wall time (s, feature caching included) and median seconds per step of each training
    stage, and how much faster a stage-1 step is than a stage-2, pretraining or full-training step."""
    from armpose.viz_train import read_history, seconds_per_step
    out = {}
    for s in TRAINING_STAGES:
        hist = root / "models" / s / "history.csv"
        if hist.exists():
            out[s] = {"wall_s": round(training_minutes(root, [s]) * 60, 1),
                      "s_per_step": round(seconds_per_step(read_history(hist)), 4)}
    if "transfer_stage1" in out:
        s1 = out["transfer_stage1"]["s_per_step"]
        out["stage1_step_speedup"] = {s: round(out[s]["s_per_step"] / s1, 2) for s in TRAINING_STAGES
                                      if s in out and s != "transfer_stage1" and s1 > 0}
    return out


def run(params: dict, root: Path | None = None) -> dict:
    """Evaluate both models and write every result file; returns the metrics dict."""
    root = Path(root or project_root())
    cfg, base = params["evaluate"], params["base"]
    types = list(base["robot_types"])
    data_dir, res = root / "data" / "labels", root / RESULTS
    metrics, preds = {}, {}
    for name, ckpt in cfg["models"].items():
        m, pred, truth = evaluate_checkpoint(root / ckpt, data_dir, base, "test", int(cfg["batch_size"]),
                                             mirror=bool(cfg.get("mirror_test", False)) and name == "transfer",
                                             zoom=bool(cfg.get("zoom_test", False)) and name == "transfer",
                                             fit=FitSettings() if cfg.get("kinematic_fit", False) and name == "transfer"
                                             else None,
                                             zoom_on_mirror=bool(cfg.get("zoom_on_mirror", False)) and name == "transfer")
        for key in ("zoom_test", "kinematic_fit"):
            if key in m:
                m[key]["on_mirror_test"] = bool(cfg.get("zoom_on_mirror", False))
        if "kinematic_fit" in m:
            sigmas_on_mirror = m["kinematic_fit"]["sigmas_on_mirror_test"]
            if sigmas_on_mirror != m["kinematic_fit"]["on_mirror_test"]:
                log.warning("%s: the fit's weights were measured on %s passes but evaluate fits %s ones; set "
                            "transfer_stage2.fit_sigmas_on_mirror to evaluate.zoom_on_mirror", ckpt,
                            *(("mirror-averaged", "single") if sigmas_on_mirror else ("single", "mirror-averaged")))
        metrics[name] = {"checkpoint": ckpt, "test": m}
        preds[name] = (pred, truth)
    for name, pred_truth in preds.items():
        metrics[name]["test"].update(recorded_metrics(pred_truth, data_dir, root, params, name == "transfer"))
    latency_path = root / RESULTS / "latency.json"
    metrics["latency"] = json.loads(latency_path.read_text()) if latency_path.exists() else {}
    metrics["timing"] = training_timing(root)
    atomic_write_json(res / "metrics.json", metrics)

    # figures and the data behind them
    plots, figs = res / "plots", res / "figures"
    sweep = read_csv(plots / "transfer_sweep.csv")
    if sweep:
        save_figure(viz_eval.sweep_figure(sweep), figs / "a_transfer_sweep.png")
    histories = {s: load_checkpoint(root / "models" / s / "last.pt")["extra"]["history"]
                 for s in ("pretrain", "transfer_stage1", "transfer_stage2")}
    curve = viz_eval.loss_curve_rows(histories)
    write_csv(plots / "loss_curve.csv", curve)
    save_figure(viz_eval.loss_curve_figure(curve), figs / "b_loss_curve.png")
    pred, truth = preds["transfer"]
    dist = distance_rows(pred, truth, types, np.linspace(*cfg["distance_range"], int(cfg["distance_bins"]) + 1))
    write_csv(plots / "error_by_distance.csv", dist)
    save_figure(viz_eval.distance_figure(dist), figs / "c_error_by_distance.png")
    cols = example_columns(root / cfg["models"]["transfer"], data_dir, pred, truth, types, int(base["seed"]))
    save_figure(viz_eval.examples_figure(cols), figs / "d_examples.png")
    comp = []
    for name, stages in (("transfer", ["pretrain", "transfer_stage1", "transfer_stage2"]), ("train_full", ["train_full"])):
        if name in metrics:
            for fam, m in metrics[name]["test"]["by_family"].items():
                comp.append({"model": name, "family": fam, "joint_median_cm": m["joint_median_cm"],
                             "type_accuracy": m["type_accuracy"], "mask_accuracy": m["mask_accuracy"],
                             "train_minutes": round(training_minutes(root, stages), 2)})
    write_csv(plots / "transfer_vs_full.csv", comp)
    save_figure(viz_eval.comparison_figure(comp), figs / "e_transfer_vs_full.png")
    if metrics["latency"]:
        lat = metrics["latency"]
        write_csv(plots / "latency.csv", [{"device": d, "median_ms": lat[d]["batch1_median_ms"], "p95_ms": lat[d]["batch1_p95_ms"]}
                                          for d in ("cpu", "cuda") if d in lat])
        save_figure(viz_eval.latency_figure(lat), figs / "f_latency.png")
    conf = metrics["transfer"]["test"]["confusion"]
    write_csv(plots / "confusion.csv", [{"actual": conf["labels"][a], "predicted": conf["labels"][p]}
                                        for a, row in enumerate(conf["matrix"]) for p, n in enumerate(row) for _ in range(n)])
    atomic_write_text(res / "results_table.md", results_table(metrics, cfg["data_note"], cfg.get("headline", "single")))
    atomic_write_json(res / "env.json", environment(root, cfg["profile"]))
    return metrics


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="armpose evaluate", description=__doc__)
    ap.add_argument("--params", default=None, help="params file (default: the project's params.yaml)")
    ap.add_argument("--root", default=None, help="project root holding data/, models/ and results/")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    metrics = run(load_params(args.params), args.root)
    for fam, m in metrics["transfer"]["test"]["by_family"].items():
        print(f"evaluate {fam:>5}: mask acc {100 * m['mask_accuracy']:.1f} %, type acc {100 * m['type_accuracy']:.1f} %, "
              f"joint median {m['joint_median_cm']:.2f} cm, base median {m['base_median_cm']:.2f} cm")
    print(f"evaluate: wrote {Path(args.root or project_root()) / RESULTS / 'results_table.md'}")


if __name__ == "__main__":
    main()
