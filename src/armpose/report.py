"""The results table (paper Table II side by side with ours) and the run's environment record.

The paper's numbers are quoted from Miseikis et al. 2019, Table II ("Summary of the Transfer
Learning results (using 500 samples of each robot type for training) on the test set"),
measured on real camera images. Ours come from ``results/metrics.json`` of the last run,
measured on the held-out split of our data (synthetic renders unless recorded data is added).
"""
from __future__ import annotations

import json
import os
import platform
import subprocess
from importlib import metadata
from pathlib import Path
from typing import Mapping

PAPER_TABLE_II = {
    "UR": {"mask_accuracy": 0.970, "type_accuracy": 0.975, "joint_median_cm": 3.12, "base_median_cm": 2.42},
    "KUKA": {"mask_accuracy": 0.977, "type_accuracy": 1.000, "joint_median_cm": 3.30, "base_median_cm": 2.36},
    "Panda": {"mask_accuracy": 0.943, "type_accuracy": 0.961, "joint_median_cm": 3.64, "base_median_cm": 3.01},
}
PAPER_LATENCY_MS = (19, 23)
HIGHER_IS_BETTER = {"mask_accuracy": True, "type_accuracy": True, "joint_median_cm": False, "base_median_cm": False}
ROW_NAMES = {"mask_accuracy": "Mask accuracy, %", "type_accuracy": "Robot type accuracy, %",
             "joint_median_cm": "Joint position error (median), cm", "base_median_cm": "Base position error (median), cm"}
PACKAGES = ("torch", "numpy", "pybullet", "pytorch-kinematics", "opencv-python-headless", "dvc", "matplotlib")


def _fmt(key: str, value: float) -> str:
    if value != value:  # NaN
        return "n/a"
    return f"{100 * value:.1f}" if key in ("mask_accuracy", "type_accuracy") else f"{value:.2f}"


def beats_paper(ours: Mapping, family: str, key: str) -> bool:
    paper = PAPER_TABLE_II[family][key]
    return ours[key] >= paper if HIGHER_IS_BETTER[key] else ours[key] <= paper


def results_table(metrics: Mapping, data_note: str) -> str:
    """Markdown: the paper's Table II and ours (two-stage transfer, and full training) per family,
    extra metrics, latency, and notes on what is still short of the paper."""
    fams = [f for f in PAPER_TABLE_II if f in metrics["transfer"]["test"]["by_family"]]
    ours = {f: metrics["transfer"]["test"]["by_family"][f] for f in fams}
    full = metrics.get("train_full", {}).get("test", {}).get("by_family", {})
    head = "| Measure | " + " | ".join(f"{f} paper | {f} ours" for f in fams) + " |"
    lines = [head, "|---|" + "---:|---:|" * len(fams)]
    short = []
    for key, name in ROW_NAMES.items():
        cells = []
        for f in fams:
            mark = "**" if beats_paper(ours[f], f, key) else ""
            cells += [_fmt(key, PAPER_TABLE_II[f][key]), f"{mark}{_fmt(key, ours[f][key])}{mark}"]
            if not beats_paper(ours[f], f, key):
                short.append(f"{f} {name.split(',')[0].lower()}: {_fmt(key, ours[f][key])} against the paper's "
                             f"{_fmt(key, PAPER_TABLE_II[f][key])}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    out = ["# Results: paper Table II and ours", "",
           f"Paper: real camera images (Miseikis et al. 2019, Table II). Ours: {data_note}", "",
           "Two-stage transfer model (`models/transfer_stage2/model.pt`), held-out test split. "
           "Bold: ours at least as good as the paper's.", "", *lines, ""]
    extra_keys = ("mask_iou", "joint_mean_cm", "add_auc_10cm", "pck_5px", "pck_10px", "frames")
    out += ["## More metrics (two-stage transfer | full training from scratch)", "",
            "| Family | " + " | ".join(extra_keys) + " | full: joint median cm | full: type acc % |",
            "|---|" + "---:|" * (len(extra_keys) + 2)]
    for f in fams:
        vals = [f"{ours[f][k]:.3f}" if k != "frames" else str(ours[f][k]) for k in extra_keys]
        fv = full.get(f, {})
        vals += [f"{fv.get('joint_median_cm', float('nan')):.2f}", f"{100 * fv.get('type_accuracy', float('nan')):.1f}"]
        out.append(f"| {f} | " + " | ".join(vals) + " |")
    pose = metrics["transfer"]["test"].get("camera_pose", {}).get("by_family", {})
    if pose:
        out += ["", "## Camera-to-robot pose from one image (beyond the paper)", "",
                "The predicted base and joints aligned with forward kinematics of the joint encoders "
                "(robust rigid fit): the Eye-to-Hand transform without a calibration.", "",
                "| Family | frames | rotation median deg | translation median cm | ADD median cm | ADD AUC 10 cm |",
                "|---|---:|---:|---:|---:|---:|"]
        for f, m in pose.items():
            if m.get("frames"):
                out.append(f"| {f} | {m['frames']} | {m['rotation_median_deg']:.2f} | {m['translation_median_cm']:.2f} | "
                           f"{m['add_median_cm']:.2f} | {m['add_auc_10cm']:.3f} |")
    recorded = metrics["transfer"]["test"].get("by_source", {}).get("recorded")
    if recorded:
        out += ["", "## Recorded test recordings (the real-world path), two-stage transfer", "",
                "| Family | frames | mask acc % | type acc % | joint median cm | base median cm |", "|---|---:|---:|---:|---:|---:|"]
        for f, m in recorded["by_family"].items():
            out.append(f"| {f} | {m['frames']} | {100 * m['mask_accuracy']:.1f} | {100 * m['type_accuracy']:.1f} | "
                       f"{m['joint_median_cm']:.2f} | {m['base_median_cm']:.2f} |")
    lat = metrics.get("latency", {})
    if "cpu" in lat:
        c = lat["cpu"]
        out += ["", f"Latency, batch 1: median **{c['batch1_median_ms']:.1f} ms** (p95 {c['batch1_p95_ms']:.1f} ms) "
                    f"on this machine's CPU with {c['threads']} threads ({c.get('processor', '')}); "
                    f"paper: {PAPER_LATENCY_MS[0]}-{PAPER_LATENCY_MS[1]} ms on a GTX 1080 Ti."]
        if "cuda" in lat:
            out.append(f"On {lat['cuda']['device']}: median {lat['cuda']['batch1_median_ms']:.1f} ms.")
    timing = metrics.get("timing", {})
    stages = [s for s in timing if isinstance(timing[s], dict) and "wall_s" in timing[s]]
    if stages:
        out += ["", "Training wall time: " + ", ".join(f"{s} {timing[s]['wall_s'] / 60:.1f} min "
                                                     f"({1000 * timing[s]['s_per_step']:.0f} ms/step)" for s in stages) + "."]
        speed = timing.get("stage1_step_speedup", {})
        if speed:
            out.append("A transfer stage-1 step (heads only, on cached trunk features) is "
                       + ", ".join(f"{v:.1f}x faster than a {k} step" for k, v in speed.items()) + ".")
    out += ["", "## Still short of the paper", ""]
    out += [f"- {s}" for s in short] or ["- nothing in the table above."]
    return "\n".join(out) + "\n"


def git_hash(root: Path) -> str:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def environment(root: Path, profile_note: str) -> dict:
    """The git hash, the machine, the package versions and the profile of this run."""
    versions = {}
    for pkg in PACKAGES:
        try:
            versions[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            versions[pkg] = None
    return {"git": git_hash(root), "profile": profile_note, "python": platform.python_version(),
            "machine": {"processor": platform.processor() or platform.machine(), "cpu_count": os.cpu_count(),
                        "platform": platform.platform()},
            "packages": versions}


def dumps(obj) -> str:
    return json.dumps(obj, indent=2, sort_keys=False)


README_START, README_END = "<!-- results:start -->", "<!-- results:end -->"


def update_readme(root: Path) -> bool:
    """Copy ``results/results_table.md`` (minus its title) between the README's result markers.
    Returns True if the README changed. ``python -m armpose.report`` runs it."""
    readme, table = Path(root) / "README.md", Path(root) / "results" / "results_table.md"
    text, body = readme.read_text(), table.read_text().split("\n", 1)[1].strip()
    body = "\n".join("#" + line if line.startswith("## ") else line for line in body.splitlines())  # under ## Results
    if README_START not in text or README_END not in text:
        raise ValueError(f"{readme}: no {README_START} ... {README_END} markers")
    head, rest = text.split(README_START, 1)
    new = f"{head}{README_START}\n{body}\n{README_END}{rest.split(README_END, 1)[1]}"
    if new != text:
        from armpose.io import atomic_write_text
        atomic_write_text(readme, new)
    return new != text


if __name__ == "__main__":
    from armpose.config import project_root
    print("README updated" if update_readme(project_root()) else "README already up to date")
