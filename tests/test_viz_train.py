"""armpose.viz_train: the figures and tables of the training notebooks, on a fake history and a tiny model."""
from __future__ import annotations

import copy
import io
import json

import numpy as np
import pytest
from matplotlib.figure import Figure

from armpose import viz, viz_train
from armpose.config import profile_params
from armpose.model import build_model, count_parameters
from armpose.train import HISTORY_FIELDS, write_history


@pytest.fixture(scope="module")
def tiny_model():
    return build_model({"width": 4})


def _rows(n: int, stage: str = "transfer_stage1", eval_every: int = 3, dt: float = 0.5) -> list[dict]:
    """A fake history as train() writes it: wall_s stamped before validating, so a validation's
    time (0.7 s) lands in the next step; the first step carries 2 s of start-up."""
    rows, wall = [], 2.0
    for s in range(1, n + 1):
        wall += dt + (0.7 if s > 1 and (s - 1) % eval_every == 0 else 0.0)
        row = {"step": s, "stage": stage, "wall_s": wall,
               "lr": 1e-3, "total": 3.0 / s, "mask": 1.0 / s, "joints": 0.5, "base": 0.4, "type": 1.6}
        if s % eval_every == 0:
            row.update(val_total=2.0, val_joint_cm=30.0, val_base_cm=20.0, val_type_acc=0.5, val_mask_acc=0.9)
        rows.append(row)
    return rows


def _history(tmp_path, n=7, **kw):
    path = tmp_path / "history.csv"
    write_history(path, _rows(n, **kw))
    return viz_train.read_history(path)


def _png(fig: Figure) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=30)
    return buf.getvalue()


def test_read_history_columns(tmp_path):
    h = _history(tmp_path, n=7)
    assert set(h) == set(HISTORY_FIELDS)
    np.testing.assert_array_equal(h["step"], np.arange(1, 8))
    assert h["stage"].dtype.kind == "U" and (h["stage"] == "transfer_stage1").all()
    assert h["total"].dtype == np.float64
    np.testing.assert_array_equal(~np.isnan(h["val_total"]), [s % 3 == 0 for s in range(1, 8)])
    np.testing.assert_array_equal(viz_train.has_validation(h), ~np.isnan(h["val_total"]))
    (tmp_path / "bad.csv").write_text("a,b\n1,2\n")
    with pytest.raises(ValueError, match="step"):
        viz_train.read_history(tmp_path / "bad.csv")
    with pytest.raises(FileNotFoundError):
        viz_train.read_history(tmp_path / "missing.csv")


def test_seconds_per_step_leaves_out_start_up_and_validation(tmp_path):
    h = _history(tmp_path, n=9, dt=0.5)
    assert viz_train.seconds_per_step(h) == pytest.approx(0.5)
    h = _history(tmp_path, n=4, dt=0.5, eval_every=2)    # steps 2 and 4 remain
    assert viz_train.seconds_per_step(h) == pytest.approx(0.5)
    one = {"step": np.array([1.0]), "wall_s": np.array([2.0]), "val_total": np.array([1.0])}
    assert viz_train.seconds_per_step(one) == pytest.approx(2.0)


def test_smooth_keeps_first_value_and_constant():
    np.testing.assert_allclose(viz_train.smooth(np.full(5, 2.0)), 2.0)
    y = viz_train.smooth(np.array([4.0, 0.0, 0.0]))
    assert y[0] == 4.0 and y[1] < 4.0 and y[2] < y[1]


def test_loss_and_stage_figures(tmp_path):
    h1 = _history(tmp_path, n=6)
    h2 = _history(tmp_path, n=60, stage="transfer_stage2", eval_every=20)   # long enough to be smoothed
    for fig in (viz_train.loss_curves_figure(h1, "stage 1"), viz_train.loss_curves_figure(h2),
                viz_train.stages_figure(h1, h2)):
        assert isinstance(fig, Figure)
        assert _png(fig)[:4] == b"\x89PNG"
    no_val = {k: v for k, v in h1.items() if not k.startswith("val_")}
    assert isinstance(viz_train.loss_curves_figure(no_val), Figure)
    ax = viz_train.stages_figure(h1, h2).axes[0]
    assert ax.get_xlim()[1] == pytest.approx(6 + 60)


def test_group_table_and_trainable_counts(tiny_model):
    total = count_parameters(tiny_model)
    rows = viz_train.group_table(tiny_model, {"s1": ["heads"], "s2": ["trunk.late", "mask_decoder", "heads"]})
    assert [r["group"] for r in rows] == [*viz_train.LEAF_GROUPS, "total"]
    assert sum(r["params"] for r in rows[:-1]) == rows[-1]["params"] == total
    assert sum(r["share"] for r in rows[:-1]) == pytest.approx(1.0)
    by = {r["group"]: r for r in rows}
    assert by["heads.joints"]["s1"] == "yes" and by["trunk.late"]["s1"] == "-" and by["trunk.late"]["s2"] == "yes"
    assert by["trunk.early"]["s2"] == "-"
    heads = sum(count_parameters(tiny_model, g) for g in ("heads.neck", "heads.joints", "heads.base", "heads.robot_type"))
    c = viz_train.trainable_counts(tiny_model, ["heads"])
    assert c["trainable"] == heads and c["trainable"] + c["frozen"] == c["total"] == total
    assert by["total"]["s1"] == f"{heads:,}"
    assert all(p.requires_grad for p in tiny_model.parameters()), "trainable_counts left flags changed"
    assert "total" in viz.format_table(rows, percent=("share",))


def test_is_trainable_and_colors():
    assert viz_train.is_trainable("heads.base", ["heads"])
    assert viz_train.is_trainable("heads", ["heads.base"])
    assert not viz_train.is_trainable("trunk.early", ["trunk.late", "heads"])
    s1, s2 = ["heads"], ["trunk.late", "heads"]
    assert viz_train.group_color("heads.joints", s1, s2) == viz_train.STAGE1_COLOR
    assert viz_train.group_color("trunk.late", s1, s2) == viz_train.STAGE2_COLOR
    assert viz_train.group_color("trunk.early", s1, s2) == viz_train.FROZEN_COLOR


def test_architecture_figure(tiny_model):
    params = profile_params("quick")
    fig = viz_train.architecture_figure(params, tiny_model)
    assert isinstance(fig, Figure)
    texts = " ".join(t.get_text() for t in fig.axes[0].texts)
    for g in viz_train.LEAF_GROUPS:
        assert g in texts
    assert "x 1.2" in texts and "x 0.6" in texts
    assert _png(fig)[:4] == b"\x89PNG"


def test_frozen_check(tiny_model):
    a = copy.deepcopy(tiny_model.state_dict())
    b = copy.deepcopy(a)
    for k in b:
        if k.startswith("heads.") and b[k].is_floating_point():
            b[k] = b[k] + 0.25
    rows = viz_train.frozen_check({"model": a}, b, viz_train.LEAF_GROUPS, trainable=["heads"])
    by = {r["group"]: r for r in rows}
    assert all(r["ok"] for r in rows)
    assert by["trunk.early"]["unchanged"] and by["trunk.early"]["frozen"] and by["trunk.early"]["max_abs_diff"] == 0
    assert not by["heads.joints"]["unchanged"] and by["heads.joints"]["max_abs_diff"] == pytest.approx(0.25)
    assert sum(r["tensors"] for r in rows) == len(a)
    b["trunk.late.stage4.conv1.0.weight"] = b["trunk.late.stage4.conv1.0.weight"] + 1
    assert not {r["group"]: r for r in viz_train.frozen_check(a, b, trainable=["heads"])}["trunk.late"]["ok"]
    assert "ok" not in viz_train.frozen_check(a, b)[0]
    del b["heads.base.log_depth"]
    with pytest.raises(KeyError):
        viz_train.frozen_check(a, b)


def test_frozen_check_reads_checkpoint_files(tiny_model, tmp_path):
    from armpose.train import save_checkpoint
    save_checkpoint(tmp_path / "a.pt", tiny_model, None, None, 0, "x", {})
    rows = viz_train.frozen_check(tmp_path / "a.pt", tiny_model)
    assert all(r["unchanged"] for r in rows)


def test_transfer_set_table_and_summaries(tmp_path):
    params = profile_params("quick")
    robot = np.repeat(np.arange(5), 30)
    split = np.tile(np.r_[np.zeros(20, np.uint8), np.ones(10, np.uint8)], 5)
    rows = viz_train.transfer_set_table({"robot": robot, "split": split}, params, "transfer_stage1")
    per_type = params["transfer_stage1"]["per_type"]
    assert [r["robot"] for r in rows] == params["transfer_stage1"]["robots"]
    assert all(r["available"] == 20 and r["used"] == min(20, per_type) for r in rows)

    out = tmp_path / "models" / "pretrain"
    out.mkdir(parents=True)
    summary = {"stage": "pretrain", "steps": 6, "stopped_on_plateau": False, "wall_s": 3.0, "s_per_step": 0.5,
               "num_train_frames": 48, "val_total": 2.0, "val_joint_cm": 31.0, "val_base_cm": 22.0,
               "val_type_acc": 0.5, "val_mask_acc": 0.875}
    (out / "summary.json").write_text(json.dumps(summary))
    table = viz_train.summaries_table(tmp_path, ["pretrain", "transfer_stage1"])
    assert len(table) == 1 and table[0]["steps"] == 6 and table[0]["val_joint_cm"] == 31.0
    text = viz_train.format_summary(summary)
    assert "87.5 %" in text and "31.0 cm" in text
