"""Stage ``sweep``: transfer learning with N samples per robot type, for several N (paper Fig. 6a).

For each ``N`` in ``params["sweep"]["sizes"]``, runs the transfer stages listed in
``params["sweep"]["stages"]`` (``transfer_stage1`` alone on the default CPU profile, both
stages in the paper profile) from the pretrained weights, each with its own params section
plus ``per_type = N`` and the ``overrides`` of the sweep section, into ``models/sweep/n<N>/``.
Writes ``results/plots/transfer_sweep.csv``: per N and stage, the final training loss (mean
of the last ``tail`` steps), the final validation loss and metrics, the steps and wall time.
"""
from __future__ import annotations

import argparse
import csv
import io
import logging
from pathlib import Path

import numpy as np

from armpose.config import load_params, project_root
from armpose.io import atomic_write_bytes
from armpose.distill import resolve_teacher
from armpose.train import load_checkpoint, train

log = logging.getLogger(__name__)
FIELDS = ["per_type", "stage", "steps", "wall_s", "train_loss", "val_total", "val_joint_cm", "val_base_cm",
          "val_type_acc", "val_mask_acc"]
OUTPUT = Path("results/plots/transfer_sweep.csv")


def final_train_loss(history: list[dict], tail: int) -> float:
    """Mean total training loss of the last ``tail`` steps."""
    return float(np.mean([row["total"] for row in history[-tail:]])) if history else float("nan")


def run(params: dict, root: Path | None = None) -> dict:
    """Run the sweep; returns ``{"rows": [...], "csv": path}``."""
    root = Path(root or project_root())
    cfg = params["sweep"]
    rows = []
    for n in cfg["sizes"]:
        init = root / "models" / "pretrain" / "model.pt"
        for stage in cfg["stages"]:
            stage_cfg = resolve_teacher({**params[stage], **cfg.get("overrides", {}), "per_type": int(n),
                                         "init_from": str(init)}, root)
            out = root / "models" / "sweep" / f"n{int(n)}" / stage
            summary = train(f"sweep_{stage}", stage_cfg, params["base"], root / "data" / "labels", out)
            history = load_checkpoint(out / "last.pt")["extra"]["history"]
            rows.append({"per_type": int(n), "stage": stage, "steps": summary["steps"], "wall_s": summary["wall_s"],
                         "train_loss": final_train_loss(history, int(cfg.get("tail", 50))),
                         **{k: summary.get(k, float("nan")) for k in FIELDS[5:]}})
            log.info("sweep N=%d %s: %s", n, stage, rows[-1])
            init = out / "model.pt"
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=FIELDS)
    writer.writeheader()
    writer.writerows(rows)
    atomic_write_bytes(root / OUTPUT, buf.getvalue().encode())
    return {"rows": rows, "csv": root / OUTPUT}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="armpose sweep", description=__doc__)
    ap.add_argument("--params", default=None, help="params file (default: the project's params.yaml)")
    ap.add_argument("--root", default=None, help="project root holding data/ and models/")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    res = run(load_params(args.params), args.root)
    for row in res["rows"]:
        print(f"sweep N={row['per_type']:>5} {row['stage']}: {row['steps']} steps, {row['wall_s']:.0f} s, "
              f"train loss {row['train_loss']:.3f}, val loss {row['val_total']:.3f}")
    print(f"sweep: wrote {res['csv']}")


if __name__ == "__main__":
    main()
