"""The evaluation figures (paper Fig. 5 and 6, plus transfer against full training and latency).

Each ``*_figure`` function takes plain data (CSV rows or arrays, the same data the
``evaluate`` stage writes to ``results/plots/``) and returns a matplotlib Figure; the stage
saves them as PNG in ``results/figures/``. Positions are metres in the camera optical frame,
errors are reported in cm.
"""
from __future__ import annotations

from typing import Mapping, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

FAMILY_COLORS = {"UR": "tab:blue", "KUKA": "tab:orange", "Panda": "tab:green"}
STAGE_SHADES = {"transfer_stage1": ("tab:orange", 0.12), "transfer_stage2": ("tab:green", 0.12)}


def sweep_figure(rows: Sequence[Mapping]) -> Figure:
    """(a) paper Fig. 6a: final loss and training time against transfer samples per type."""
    fig, ax = plt.subplots(figsize=(6, 3.6))
    ax2 = ax.twinx()
    for stage in dict.fromkeys(r["stage"] for r in rows):
        sel = [r for r in rows if r["stage"] == stage]
        n = [int(r["per_type"]) for r in sel]
        ax.plot(n, [float(r["train_loss"]) for r in sel], "o-", label=f"{stage}: final train loss")
        ax.plot(n, [float(r["val_total"]) for r in sel], "s--", label=f"{stage}: validation loss")
        ax2.plot(n, [float(r["wall_s"]) / 60 for r in sel], "^:", color="gray", label=f"{stage}: time")
    ax.set_xlabel("transfer samples per robot type")
    ax.set_ylabel("loss")
    ax2.set_ylabel("training time (min)")
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = ax2.get_legend_handles_labels()
    ax.legend(h1 + h2, l1 + l2, fontsize=7, loc="upper right")
    ax.set_title("Loss and time against transfer-set size (Fig. 6a)")
    fig.tight_layout()
    return fig


def loss_curve_rows(histories: Mapping[str, Sequence[Mapping]]) -> list[dict]:
    """One row per step over consecutive stages (``global_step`` counts on across stages)."""
    rows, offset = [], 0
    for stage, hist in histories.items():
        for r in hist:
            rows.append({"global_step": offset + int(r["step"]), "stage": stage, "total": float(r["total"]),
                         "joints": float(r["joints"]), "base": float(r["base"]), "type": float(r["type"]),
                         "mask": float(r["mask"]) if r.get("mask") not in (None, "") else float("nan")})
        offset += int(hist[-1]["step"]) if hist else 0
    return rows


def trailing_mean(y: np.ndarray, k: int) -> np.ndarray:
    """Mean of the last ``k`` values at each point (fewer at the start): no edge artefacts."""
    c = np.cumsum(np.concatenate([[0.0], y]))
    n = np.minimum(np.arange(1, len(y) + 1), k)
    return (c[1:] - c[np.arange(1, len(y) + 1) - n]) / n


def loss_curve_figure(rows: Sequence[Mapping], smooth: int = 25) -> Figure:
    """(b) paper Fig. 6b: training loss against iterations, transfer stages 1 and 2 shaded."""
    fig, ax = plt.subplots(figsize=(7, 3.6))
    step = np.array([r["global_step"] for r in rows], float)
    stages = [r["stage"] for r in rows]
    for term, style in (("total", "-"), ("joints", "--"), ("base", ":")):
        y = np.array([r[term] for r in rows], float)
        for i, stage in enumerate(dict.fromkeys(stages)):      # smoothed within each stage only
            sel = np.array([n == stage for n in stages])
            ax.plot(step[sel], trailing_mean(y[sel], smooth), style, lw=1, color=f"C{('total', 'joints', 'base').index(term)}",
                    label=term if i == 0 else None)
    for stage, (color, alpha) in STAGE_SHADES.items():
        s = step[[i for i, n in enumerate(stages) if n == stage]]
        if len(s):
            ax.axvspan(s.min(), s.max(), color=color, alpha=alpha, label=stage.replace("transfer_", ""))
    ax.set_yscale("log")
    ax.set_xlabel("iteration (pretraining, then transfer)")
    ax.set_ylabel("training loss (trailing mean)")
    ax.legend(fontsize=7)
    ax.set_title("Training loss over the stages (Fig. 6b)")
    fig.tight_layout()
    return fig


def distance_figure(rows: Sequence[Mapping]) -> Figure:
    """(c) paper Fig. 6c: median joint error against camera distance, one line per family."""
    fig, ax = plt.subplots(figsize=(6, 3.6))
    for fam in dict.fromkeys(r["family"] for r in rows):
        sel = [r for r in rows if r["family"] == fam and int(r["frames"]) > 0]
        mid = [(float(r["distance_lo_m"]) + float(r["distance_hi_m"])) / 2 for r in sel]
        ax.plot(mid, [float(r["joint_median_cm"]) for r in sel], "o-", color=FAMILY_COLORS.get(fam), label=fam)
    ax.set_xlabel("camera distance to the robot (m)")
    ax.set_ylabel("median 3D joint error (cm)")
    ax.legend()
    ax.set_title("Joint error against camera distance (Fig. 6c)")
    fig.tight_layout()
    return fig


def examples_figure(columns: Sequence[Mapping]) -> Figure:
    """(d) paper Fig. 5: one column per family. Row 1 estimated joints (red circles) against the
    truth (green crosses), row 2 the estimated mask, row 3 the estimated base (red) and true (green).
    Each column: ``image`` (H, W, 3) uint8, ``pred_uv``/``true_uv`` (J, 2), ``mask`` (H, W) bool,
    ``pred_base_uv``/``true_base_uv`` (2,), ``title``."""
    fig, axes = plt.subplots(3, len(columns), figsize=(3.2 * len(columns), 7.5), squeeze=False)
    for c, col in enumerate(columns):
        a = axes[:, c]
        a[0].imshow(col["image"])
        a[0].plot(*np.asarray(col["true_uv"]).T, "x", color="lime", ms=8, mew=2)
        a[0].plot(*np.asarray(col["pred_uv"]).T, "o", mfc="none", color="red", ms=8, mew=1.5)
        a[1].imshow(col["image"])
        a[1].imshow(np.ma.masked_where(~col["mask"], col["mask"]), cmap="autumn", alpha=0.6)
        a[2].imshow(col["image"])
        a[2].plot(*col["true_base_uv"], "x", color="lime", ms=10, mew=2)
        a[2].plot(*col["pred_base_uv"], "o", mfc="none", color="red", ms=10, mew=2)
        a[0].set_title(col["title"], fontsize=9)
        for ax in a:
            ax.set_xticks([])
            ax.set_yticks([])
    for r, name in enumerate(("joints", "mask", "base")):
        axes[r, 0].set_ylabel(name)
    fig.suptitle("Test images: estimate (red) against truth (green) (Fig. 5)")
    fig.tight_layout()
    return fig


def comparison_figure(rows: Sequence[Mapping]) -> Figure:
    """(e) two-stage transfer against full training: joint error, type accuracy, wall time."""
    fig, axes = plt.subplots(1, 3, figsize=(10, 3.4))
    fams = list(dict.fromkeys(r["family"] for r in rows))
    models = list(dict.fromkeys(r["model"] for r in rows))
    x = np.arange(len(fams))
    width = 0.8 / max(1, len(models))
    for i, m in enumerate(models):
        sel = {r["family"]: r for r in rows if r["model"] == m}
        axes[0].bar(x + i * width, [float(sel[f]["joint_median_cm"]) for f in fams], width, label=m)
        axes[1].bar(x + i * width, [100 * float(sel[f]["type_accuracy"]) for f in fams], width, label=m)
        axes[2].bar(i, float(next(iter(sel.values()))["train_minutes"]), 0.6, label=m)
    for ax, title in zip(axes[:2], ("median joint error (cm)", "type accuracy (%)")):
        ax.set_xticks(x + width * (len(models) - 1) / 2, fams)
        ax.set_title(title, fontsize=9)
    axes[2].set_xticks(range(len(models)), models)
    axes[2].set_title("training time (min)", fontsize=9)
    axes[0].legend(fontsize=7)
    fig.suptitle("Two-stage transfer against full training")
    fig.tight_layout()
    return fig


def latency_figure(latency: Mapping) -> Figure:
    """(f) forward latency per frame at batch 1 against the paper's 19-23 ms on a GTX 1080 Ti."""
    labels, med, p95 = [], [], []
    for dev in ("cpu", "cuda"):
        if dev in latency:
            name = f"ours, CPU {latency[dev].get('threads', '')} threads" if dev == "cpu" else f"ours, {latency[dev]['device']}"
            labels.append(name)
            med.append(latency[dev]["batch1_median_ms"])
            p95.append(latency[dev]["batch1_p95_ms"])
    labels.append("paper, GTX 1080 Ti")
    lo, hi = latency.get("paper_ms", [19, 23])
    med.append((lo + hi) / 2)
    p95.append(hi)
    fig, ax = plt.subplots(figsize=(6, 3))
    y = np.arange(len(labels))
    ax.barh(y, med, color=["tab:blue"] * (len(labels) - 1) + ["tab:gray"], label="median")
    ax.errorbar(med, y, xerr=[np.zeros(len(med)), np.array(p95) - np.array(med)], fmt="none", color="k",
                capsize=4, label="to p95 (paper: range)")
    ax.axvline(latency.get("target_cpu_median_ms", 15.0), color="tab:red", ls="--", lw=1, label="CPU target")
    ax.set_yticks(y, labels, fontsize=8)
    ax.set_xlabel("ms per frame, batch 1")
    ax.legend(fontsize=7)
    ax.set_title("Latency (f)")
    fig.tight_layout()
    return fig
