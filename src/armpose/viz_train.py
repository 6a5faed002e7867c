"""Figures and tables for the narrated notebooks of the training stages (03-05).

- :func:`architecture_figure`: the multi-objective CNN drawn as boxes and arrows, in the spirit
  of the paper's Fig. 4, coloured by which layer groups learn in transfer stage 1 and stage 2;
- :func:`group_table`, :func:`trainable_counts`: parameters per layer group, trainable or not;
- :func:`read_history`, :func:`loss_curves_figure`, :func:`stages_figure`,
  :func:`seconds_per_step`: the per-step ``history.csv`` a training stage writes
  (:data:`armpose.train.HISTORY_FIELDS`), the paper's Fig. 6b;
- :func:`frozen_check`: are a frozen group's tensors bit-identical in two checkpoints?
- :func:`transfer_set_table`: frames per robot type in a stage's training set.

Figures are built with matplotlib's object API (:class:`matplotlib.figure.Figure`, no pyplot),
as in :mod:`armpose.viz`; tables are lists of dicts, printable with :func:`armpose.viz.format_table`.
"""
from __future__ import annotations

import csv
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import torch
from matplotlib.figure import Figure
from matplotlib.patches import FancyBboxPatch, Patch
from torch import nn

from armpose.model import build_model, group_parameters, set_trainable
from armpose.train import HISTORY_FIELDS

#: The layer groups drawn and tabulated: :data:`armpose.model.GROUPS` with ``heads`` split into
#: its three branches. Every parameter and buffer of :class:`armpose.model.ArmPoseNet` is in one.
LEAF_GROUPS: tuple[str, ...] = ("trunk.early", "trunk.late", "mask_decoder", "heads.neck",
                                "heads.joints", "heads.base", "heads.robot_type")

#: Colours of the paper's Fig. 4: blue = learns from stage 1 on (the final layers), red = learns
#: in stage 2 only (more conv layers), grey = frozen in both transfer stages.
STAGE1_COLOR = "#5b8fd9"
STAGE2_COLOR = "#e0605a"
FROZEN_COLOR = "#c8c8c8"
LOSS_TERMS = ("total", "mask", "joints", "base", "type", "distill")
VAL_FIELDS = tuple(f for f in HISTORY_FIELDS if f.startswith("val_"))


# --------------------------------------------------------------------------- layer groups

def is_trainable(group: str, trainable: Sequence[str]) -> bool:
    """Whether any parameter of ``group`` learns under the freeze list ``trainable`` (a group
    learns when it, a parent group or a sub-path of it is listed)."""
    return any(group == t or group.startswith(t + ".") or t.startswith(group + ".") for t in trainable)


def _in_group(key: str, group: str) -> bool:
    return key == group or key.startswith(group + ".")


def group_table(model: nn.Module, stages: Mapping[str, Sequence[str]] | None = None) -> list[dict]:
    """Parameters per layer group of ``model``: one row per :data:`LEAF_GROUPS` entry and a
    ``total`` row, with ``params`` (count) and ``share`` (fraction of all parameters).

    ``stages`` maps a column name to a freeze list (``params[stage]["trainable"]``); each adds a
    column, ``"yes"`` where the group learns in that stage and ``"-"`` where it is frozen (the
    total row holds the trainable count instead).
    """
    stages = dict(stages or {})
    total = sum(p.numel() for p in model.parameters())
    rows = []
    for g in LEAF_GROUPS:
        n = sum(p.numel() for p in group_parameters(model, g))
        row = {"group": g, "params": n, "share": n / total if total else 0.0}
        for name, trainable in stages.items():
            row[name] = "yes" if is_trainable(g, trainable) else "-"
        rows.append(row)
    covered = sum(r["params"] for r in rows)
    if covered != total:
        raise ValueError(f"the groups {LEAF_GROUPS} hold {covered} of the model's {total} parameters")
    last = {"group": "total", "params": total, "share": 1.0}
    for name, trainable in stages.items():
        last[name] = f"{trainable_counts(model, trainable)['trainable']:,}"
    rows.append(last)
    return rows


def trainable_counts(model: nn.Module, trainable: Sequence[str]) -> dict:
    """``{"trainable", "frozen", "total", "fraction"}`` parameter counts under the freeze list
    ``trainable``, as :func:`armpose.model.set_trainable` applies it; ``model``'s
    ``requires_grad`` flags and train/eval modes are restored afterwards."""
    flags = [p.requires_grad for p in model.parameters()]
    modes = [m.training for m in model.modules()]
    try:
        set_trainable(model, list(trainable))
        n_train = sum(p.numel() for p in model.parameters() if p.requires_grad)
    finally:
        for p, f in zip(model.parameters(), flags):
            p.requires_grad_(f)
        for m, t in zip(model.modules(), modes):
            m.training = t
    total = sum(p.numel() for p in model.parameters())
    return {"trainable": n_train, "frozen": total - n_train, "total": total,
            "fraction": n_train / total if total else 0.0}


# --------------------------------------------------------------------------- architecture

def _box(ax, x, y, w, h, text, color, fontsize=8.5, weight="normal"):
    ax.add_patch(FancyBboxPatch((x, y), w, h, boxstyle="round,pad=0.02,rounding_size=0.12",
                                facecolor=color, edgecolor="#333333", linewidth=1.0))
    ax.text(x + w / 2, y + h / 2, text, ha="center", va="center", fontsize=fontsize, weight=weight)


def _arrow(ax, start, end, label=None, rad=0.0):
    ax.annotate("", xy=end, xytext=start,
                arrowprops={"arrowstyle": "-|>", "color": "#333333", "lw": 1.0,
                            "connectionstyle": f"arc3,rad={rad}", "shrinkA": 0, "shrinkB": 0})
    if label:
        ax.text(start[0] + 0.4 * (end[0] - start[0]), start[1] + 0.4 * (end[1] - start[1]), label,
                ha="center", va="center", fontsize=7, color="#333333",
                bbox={"facecolor": "white", "edgecolor": "none", "pad": 0.8})


def group_color(group: str, stage1: Sequence[str], stage2: Sequence[str]) -> str:
    """Fig. 4's colour of ``group``: :data:`STAGE1_COLOR` if it learns in stage 1,
    :data:`STAGE2_COLOR` if only in stage 2, :data:`FROZEN_COLOR` otherwise."""
    if is_trainable(group, stage1):
        return STAGE1_COLOR
    if is_trainable(group, stage2):
        return STAGE2_COLOR
    return FROZEN_COLOR


def architecture_figure(params: dict, model: nn.Module | None = None) -> Figure:
    """The multi-objective CNN as a block diagram in the spirit of the paper's Fig. 4.

    Boxes are the layer groups (:data:`LEAF_GROUPS`) with their feature maps, strides and
    parameter counts, then the four outputs with their loss and weight (``params["base"]
    ["loss_weights"]``); colours say which groups learn in ``params["transfer_stage1"]
    ["trainable"]`` (blue) and ``params["transfer_stage2"]["trainable"]`` (red, stage 2 only).
    ``model`` defaults to ``build_model(params["base"]["model"])``; only its sizes are read.
    """
    base = params["base"]
    model = model if model is not None else build_model(base.get("model", {}))
    cfg = getattr(model, "config", {})
    w = int(cfg.get("width", 32))
    k = int(cfg.get("max_joints", base.get("max_joints", 7)))
    n_types = int(cfg.get("num_types", len(base["robot_types"])))
    size = base.get("input_size", {"width": 256, "height": 212})
    hh, ww = int(size["height"]), int(size["width"])
    s1 = params["transfer_stage1"]["trainable"]
    s2 = params["transfer_stage2"]["trainable"]
    weights = {"mask": 1.2, "joints": 1.2, "base": 1.2, "type": 0.6, **base.get("loss_weights", {})}
    count = {g: sum(p.numel() for p in group_parameters(model, g)) for g in LEAF_GROUPS}

    def n(g):
        c = count[g]
        return f"{c / 1e6:.2f} M" if c >= 1e5 else f"{c / 1e3:.1f} k"

    fig = Figure(figsize=(13, 6.2), layout="constrained")
    ax = fig.add_subplot()
    ax.set_xlim(0, 15.2)
    ax.set_ylim(0, 8.4)
    ax.set_axis_off()
    color = {g: group_color(g, s1, s2) for g in LEAF_GROUPS}

    _box(ax, 0.1, 3.55, 1.6, 1.3, f"RGB image\n3 x {hh} x {ww}\nin [0, 1]", "white")
    _box(ax, 2.3, 2.9, 2.5, 2.6, f"trunk.early\n\nstem 3x3/2, 3x3/2\nsep. residual 3x3\n-> c1 (/4, {w} ch)\n"
         f"BasicBlock/2\n-> c2 (/8, {2 * w} ch)\n\n{n('trunk.early')}", color["trunk.early"])
    _box(ax, 5.5, 2.9, 2.5, 2.6, f"trunk.late\n\nBasicBlock/2 + BasicBlock\n-> c3 (/16, {4 * w} ch)\n"
         f"BasicBlock/2\n-> c4 (/32, {8 * w} ch)\n\n{n('trunk.late')}", color["trunk.late"])
    _box(ax, 9.0, 6.3, 2.8, 1.7, f"mask_decoder\nFPN on c1..c4, 3x3 at /4,\n1x1 -> 1 logit, upsample\n"
         f"{n('mask_decoder')}", color["mask_decoder"])
    _box(ax, 5.5, 0.4, 2.5, 1.9, f"heads.neck\n1x1 laterals of c2, c3, c4\nsummed at /8 ({2 * w} ch)\n"
         f"{n('heads.neck')}", color["heads.neck"])
    _box(ax, 9.0, 4.3, 2.8, 1.4, f"heads.joints\nspatial softmax x {k},\nlog-depth, pinhole\n"
         f"{n('heads.joints')}", color["heads.joints"])
    _box(ax, 9.0, 2.4, 2.8, 1.4, f"heads.base\nspatial softmax x 1,\nlog-depth, pinhole\n"
         f"{n('heads.base')}", color["heads.base"])
    _box(ax, 9.0, 0.5, 2.8, 1.4, f"heads.robot_type\navg+max pool c4, MLP\n{n('heads.robot_type')}",
         color["heads.robot_type"])
    outs = [(6.45, f"robot mask\n1 x {hh} x {ww}\nL_mask x {weights['mask']:g}"),
            (4.3, f"3D joints\n{k} x 3 (m)\nL_Jcoords x {weights['joints']:g}"),
            (2.4, f"3D base\n3 (m)\nL_Bcoords x {weights['base']:g}"),
            (0.5, f"robot type\n{n_types} logits\nL_type x {weights['type']:g}")]
    for y, text in outs:
        _box(ax, 12.6, y, 2.4, 1.4, text, "white", fontsize=8)

    _arrow(ax, (1.8, 4.2), (2.3, 4.2))
    _arrow(ax, (4.9, 4.2), (5.5, 4.2), "c2")
    _arrow(ax, (3.55, 5.6), (9.0, 7.3), "c1, c2", rad=-0.15)
    _arrow(ax, (8.1, 5.0), (9.0, 6.8), "c3, c4")
    _arrow(ax, (6.75, 2.9), (6.75, 2.3), "c2, c3, c4")
    _arrow(ax, (8.0, 1.6), (9.0, 5.0), "[/8, xy]", rad=0.1)
    _arrow(ax, (8.0, 1.3), (9.0, 3.1))
    _arrow(ax, (8.1, 3.2), (9.0, 1.2), "c4")
    for (y, _), src_y in zip(outs, (7.15, 5.0, 3.1, 1.2)):
        _arrow(ax, (11.9, src_y), (12.6, y + 0.7))

    legend = [Patch(facecolor=STAGE1_COLOR, edgecolor="#333333", label=f"stage 1 and 2: {', '.join(s1)}"),
              Patch(facecolor=STAGE2_COLOR, edgecolor="#333333",
                    label="stage 2 only: " + ", ".join(t for t in s2 if not is_trainable(t, s1))),
              Patch(facecolor=FROZEN_COLOR, edgecolor="#333333", label="frozen in both transfer stages")]
    ax.legend(handles=legend, loc="lower left", bbox_to_anchor=(0.0, 0.0), fontsize=8, frameon=False,
              title="learns in transfer stage (pretraining trains all)", title_fontsize=8)
    total = sum(count.values())
    ax.set_title(f"Multi-objective CNN, width {w}: {total / 1e6:.2f} M parameters; "
                 f"L_final = sum of weighted losses (eq. 8)", fontsize=10)
    return fig


# --------------------------------------------------------------------------- history

def read_history(path: str | Path) -> dict[str, np.ndarray]:
    """A stage's ``history.csv`` as columns: ``"stage"`` an array of str, every other column
    float64 with NaN where the cell is empty (validation columns exist only on validation
    steps). Raises FileNotFoundError naming the file, ValueError if it has no ``step`` column."""
    path = Path(path)
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        fields = list(reader.fieldnames or [])
        rows = list(reader)
    if "step" not in fields:
        raise ValueError(f"{path}: no 'step' column (columns: {fields})")
    out: dict[str, np.ndarray] = {}
    for f in fields:
        cells = [r.get(f) or "" for r in rows]
        if f == "stage":
            out[f] = np.array(cells, dtype=str)
        else:
            out[f] = np.array([float(c) if c.strip() else np.nan for c in cells], dtype=np.float64)
    return out


def has_validation(history: Mapping[str, np.ndarray]) -> np.ndarray:
    """Boolean per step: a validation row (any ``val_*`` value present)."""
    n = len(history["step"])
    mask = np.zeros(n, dtype=bool)
    for f in VAL_FIELDS:
        if f in history:
            mask |= ~np.isnan(history[f])
    return mask


def smooth(values: np.ndarray, ema: float = 0.9) -> np.ndarray:
    """Exponential moving average (bias-corrected, so the first value is kept), NaN-free input."""
    values = np.asarray(values, dtype=np.float64)
    out = np.empty_like(values)
    acc, norm = 0.0, 0.0
    for i, v in enumerate(values):
        acc = ema * acc + (1 - ema) * v
        norm = ema * norm + (1 - ema)
        out[i] = acc / norm
    return out


def seconds_per_step(history: Mapping[str, np.ndarray]) -> float:
    """Median wall-clock seconds of one training step, from the cumulative ``wall_s`` column.

    :func:`armpose.train.train` stamps ``wall_s`` before it validates, so a validation's time
    shows up in the *next* step's increment; those steps, and the first one (start-up: first
    batch, lazy initialisation), are left out while any other step remains. The first step
    counts from 0, so a one-step history gives its wall time.
    """
    wall = np.asarray(history["wall_s"], dtype=np.float64)
    if wall.size == 0:
        return float("nan")
    dt = np.diff(np.concatenate([[0.0], wall]))
    plain = np.ones(wall.size, dtype=bool)
    plain[0] = False
    plain[1:] &= ~has_validation(history)[:-1]
    return float(np.median(dt[plain] if plain.any() else dt))


def _plot_terms(ax, step, history, smooth_from: int):
    colors = {"total": "black", "mask": "tab:red", "joints": "tab:blue", "base": "tab:green", "type": "tab:purple",
              "distill": "tab:orange"}
    for term in LOSS_TERMS:
        if term not in history or np.isnan(history[term]).all():
            continue
        y = history[term]
        if len(y) >= smooth_from:
            ax.plot(step, y, color=colors[term], alpha=0.2, lw=0.8)
            ax.plot(step, smooth(y), color=colors[term], lw=1.6 if term == "total" else 1.1, label=term)
        else:
            ax.plot(step, y, color=colors[term], marker="o", ms=3, lw=1.6 if term == "total" else 1.1, label=term)


def loss_curves_figure(history: Mapping[str, np.ndarray], title: str = "", smooth_from: int = 50) -> Figure:
    """Training loss terms against the step (left: ``total`` and ``mask``, ``joints``,
    ``base``, ``type`` and, in a stage that distils (:mod:`armpose.distill`), ``distill``, unweighted; histories of ``smooth_from`` steps or more are drawn faint
    with an EMA on top) and, right, the validation metrics where the history has any: median
    joint and base error (cm, left axis), type and mask accuracy (%, right axis)."""
    step = history["step"]
    fig = Figure(figsize=(12, 4), layout="constrained")
    ax, axv = fig.subplots(1, 2)
    _plot_terms(ax, step, history, smooth_from)
    if "val_total" in history and (~np.isnan(history["val_total"])).any():
        v = ~np.isnan(history["val_total"])
        ax.plot(step[v], history["val_total"][v], "k--s", ms=4, lw=1, label="val total")
    ax.set_xlabel("step")
    ax.set_ylabel("loss (unweighted terms; total = eq. 8)")
    ax.set_title("training loss" + (f": {title}" if title else ""))
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)

    val = has_validation(history)
    if not val.any():
        axv.text(0.5, 0.5, "no validation steps", ha="center", va="center", transform=axv.transAxes)
        axv.set_axis_off()
        return fig
    s = step[val]
    for f, label, c in (("val_joint_cm", "joint error (median)", "tab:blue"),
                        ("val_base_cm", "base error (median)", "tab:green")):
        if f in history:
            axv.plot(s, history[f][val], "-o", color=c, ms=4, label=label)
    axv.set_xlabel("step")
    axv.set_ylabel("cm")
    axv.grid(alpha=0.3)
    acc = axv.twinx()
    for f, label, c in (("val_type_acc", "type accuracy", "tab:purple"),
                        ("val_mask_acc", "mask pixel accuracy", "tab:red")):
        if f in history:
            acc.plot(s, 100 * history[f][val], "--^", color=c, ms=4, label=label)
    acc.set_ylabel("%")
    acc.set_ylim(0, 105)
    lines = axv.get_legend_handles_labels()
    lines2 = acc.get_legend_handles_labels()
    axv.legend(lines[0] + lines2[0], lines[1] + lines2[1], fontsize=8, loc="center right")
    axv.set_title("validation")
    return fig


def stages_figure(h1: Mapping[str, np.ndarray], h2: Mapping[str, np.ndarray], smooth_from: int = 50) -> Figure:
    """The paper's Fig. 6b: total training loss of transfer stage 1 then stage 2 against the
    iteration counted across both, the stage spans shaded (blue, red as in Fig. 4); validation
    totals as squares."""
    n1 = int(h1["step"][-1]) if len(h1["step"]) else 0
    x1 = np.asarray(h1["step"], dtype=float)
    x2 = np.asarray(h2["step"], dtype=float) + n1
    fig = Figure(figsize=(8, 4), layout="constrained")
    ax = fig.add_subplot()
    end = x2[-1] if len(x2) else n1
    ax.axvspan(0, n1, color=STAGE1_COLOR, alpha=0.18, lw=0)
    ax.axvspan(n1, end, color=STAGE2_COLOR, alpha=0.18, lw=0)
    for x, h in ((x1, h1), (x2, h2)):
        if not len(x):
            continue
        y = h["total"]
        if len(y) >= smooth_from:
            ax.plot(x, y, color="black", alpha=0.2, lw=0.8)
            ax.plot(x, smooth(y), color="black", lw=1.5)
        else:
            ax.plot(x, y, color="black", marker="o", ms=3, lw=1.5)
        if "val_total" in h:
            v = ~np.isnan(h["val_total"])
            ax.plot(x[v], h["val_total"][v], "s", color="#444444", mfc="white", ms=5)
    lo, hi = ax.get_ylim()
    ax.set_ylim(lo, hi + 0.1 * (hi - lo))     # headroom for the stage labels
    ax.text(n1 / 2, 0.98, "stage 1", ha="center", va="top", fontsize=9, transform=ax.get_xaxis_transform())
    ax.text((n1 + end) / 2, 0.98, "stage 2", ha="center", va="top", fontsize=9,
            transform=ax.get_xaxis_transform())
    ax.set_xlim(0, max(end, 1))
    ax.set_xlabel("iteration (both transfer stages)")
    ax.set_ylabel("total loss (eq. 8)")
    ax.set_title("two-stage transfer learning: training loss (lines), validation loss (squares)")
    ax.grid(alpha=0.3)
    return fig


# --------------------------------------------------------------------------- checkpoints

def _state_dict(ckpt) -> dict[str, torch.Tensor]:
    if isinstance(ckpt, (str, Path)):
        from armpose.train import load_checkpoint
        ckpt = load_checkpoint(Path(ckpt))
    if isinstance(ckpt, nn.Module):
        return ckpt.state_dict()
    if isinstance(ckpt, Mapping) and "model" in ckpt and isinstance(ckpt["model"], Mapping):
        return dict(ckpt["model"])
    return dict(ckpt)


def frozen_check(ckpt_a, ckpt_b, groups: Sequence[str] = LEAF_GROUPS,
                 trainable: Sequence[str] | None = None) -> list[dict]:
    """Compare two checkpoints group by group.

    ``ckpt_a``, ``ckpt_b``: checkpoint paths, checkpoint dicts (:func:`armpose.train.load_checkpoint`),
    state dicts or modules. One row per group: ``tensors`` (state-dict entries, BatchNorm running
    statistics included), ``values`` (their element count), ``changed`` (entries that differ),
    ``max_abs_diff`` over floating-point entries and ``unchanged`` (every entry bit-identical).
    With ``trainable`` (the freeze list of the stage that made ``ckpt_b``), rows also say whether
    the group was ``frozen`` and ``ok``: a frozen group unchanged, a trainable one changed.
    Raises KeyError if the two checkpoints do not hold the same entries.
    """
    a, b = _state_dict(ckpt_a), _state_dict(ckpt_b)
    if set(a) != set(b):
        diff = sorted(set(a) ^ set(b))
        raise KeyError(f"the checkpoints hold different entries, e.g. {diff[:3]}")
    rows = []
    for g in groups:
        keys = [k for k in a if _in_group(k, g)]
        changed, max_diff, values = 0, 0.0, 0
        for k in keys:
            ta, tb = a[k], b[k]
            values += ta.numel()
            if not torch.equal(ta, tb):
                changed += 1
                if ta.is_floating_point():
                    max_diff = max(max_diff, float((ta.double() - tb.double()).abs().max()))
        row = {"group": g, "tensors": len(keys), "values": values, "changed": changed,
               "max_abs_diff": max_diff, "unchanged": changed == 0}
        if trainable is not None:
            frozen = not is_trainable(g, trainable)
            row["frozen"] = frozen
            row["ok"] = row["unchanged"] if frozen else not row["unchanged"]
        rows.append(row)
    return rows


# --------------------------------------------------------------------------- data

def transfer_set_table(arrays: Mapping[str, np.ndarray], params: dict, stage: str) -> list[dict]:
    """Frames per robot type of ``stage``'s training set, drawn as :func:`armpose.train.train`
    draws it (:func:`armpose.data.transfer_set`, seed ``base.seed + seed_offset``): ``available``
    train-split frames, ``used`` in the stage, and the stage's ``per_type`` (None = all)."""
    from armpose.data import transfer_set
    base, cfg = params["base"], params[stage]
    seed = int(base["seed"]) + int(cfg.get("seed_offset", 0))
    types = [base["robot_types"].index(r) for r in cfg["robots"]]
    rows_used = transfer_set(arrays, "train", types, cfg.get("per_type"), seed)
    robot = np.asarray(arrays["robot"])
    split = np.asarray(arrays["split"])
    used = robot[rows_used]
    return [{"robot": base["robot_types"][t], "available": int(((robot == t) & (split == 0)).sum()),
             "used": int((used == t).sum()), "per_type": cfg.get("per_type")} for t in types]


def format_summary(summary: Mapping) -> str:
    """A stage's ``run`` result (or ``summary.json``) as ``key: value`` lines, cm and % rounded."""
    lines = []
    for key, v in summary.items():
        if key.endswith("_acc") and isinstance(v, float):
            text = f"{100 * v:.1f} %"
        elif key.endswith("_cm") and isinstance(v, float):
            text = f"{v:.1f} cm"
        elif isinstance(v, float):
            text = f"{v:.4g}"
        else:
            text = str(v)
        lines.append(f"{key:>26}: {text}")
    return "\n".join(lines)


def summaries_table(root: str | Path, stages: Sequence[str]) -> list[dict]:
    """One row per stage from ``<root>/models/<stage>/summary.json`` (what ``run`` returned):
    steps, whether it stopped on the plateau, training frames, seconds per step (wall time over
    steps, validation included) and the final validation metrics. Stages without a summary are
    left out."""
    import json
    rows = []
    for stage in stages:
        path = Path(root) / "models" / stage / "summary.json"
        if not path.exists():
            continue
        s = json.loads(path.read_text())
        rows.append({"stage": stage, "steps": s.get("steps"), "plateau": s.get("stopped_on_plateau"),
                     "frames": s.get("num_train_frames"), "s_per_step": s.get("s_per_step", float("nan")),
                     **{k: s.get(k, float("nan")) for k in VAL_FIELDS}})
    return rows
