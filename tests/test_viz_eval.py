"""The evaluation figures draw from plain rows, the same data the evaluate stage writes to CSV."""
import numpy as np
from matplotlib.figure import Figure

from armpose import viz_eval


def test_every_figure_draws_from_small_inputs():
    sweep = [{"per_type": n, "stage": "transfer_stage1", "train_loss": 3 - n / 500, "val_total": 3.2 - n / 600,
              "wall_s": 10 + n / 10} for n in (100, 250, 500)]
    hist = {"pretrain": [{"step": i + 1, "total": 5 - i / 10, "joints": 0.5, "base": 0.4, "type": 1.0, "mask": 0.2}
                         for i in range(20)],
            "transfer_stage1": [{"step": i + 1, "total": 3.0, "joints": 0.3, "base": 0.3, "type": 0.9, "mask": ""}
                                for i in range(10)]}
    rows = viz_eval.loss_curve_rows(hist)
    assert [r["global_step"] for r in rows][19:21] == [20, 21] and np.isnan(rows[-1]["mask"])
    dist = [{"family": f, "distance_lo_m": lo, "distance_hi_m": lo + 0.5, "frames": 3, "joint_median_cm": 10 + lo}
            for f in ("UR", "KUKA") for lo in (1.0, 1.5, 2.0)]
    img = np.zeros((20, 24, 3), np.uint8)
    col = {"image": img, "pred_uv": np.ones((6, 2)), "true_uv": np.ones((6, 2)) * 2, "mask": np.zeros((20, 24), bool),
           "pred_base_uv": np.ones(2), "true_base_uv": np.ones(2), "title": "UR"}
    comp = [{"model": m, "family": f, "joint_median_cm": 20.0, "type_accuracy": 0.7, "train_minutes": 12.0}
            for m in ("transfer", "train_full") for f in ("UR", "KUKA")]
    latency = {"cpu": {"batch1_median_ms": 9.0, "batch1_p95_ms": 11.0, "threads": 2}, "paper_ms": [19, 23]}
    figs = [viz_eval.sweep_figure(sweep), viz_eval.loss_curve_figure(rows), viz_eval.distance_figure(dist),
            viz_eval.examples_figure([col, col]), viz_eval.comparison_figure(comp), viz_eval.latency_figure(latency)]
    assert all(isinstance(f, Figure) for f in figs)


def test_trailing_mean_has_no_edge_artefacts():
    y = np.full(50, 2.0)
    assert np.allclose(viz_eval.trailing_mean(y, 10), 2.0)
    assert np.allclose(viz_eval.trailing_mean(np.arange(4.0), 2), [0, 0.5, 1.5, 2.5])
