"""The common body of the training stages: resolve paths, call :func:`armpose.train.train`.

Each training stage (``pretrain``, ``transfer_stage1``, ``transfer_stage2``, ``train_full``)
is a module of a few lines that names itself; it reads ``params['base']`` and its own section.
Outputs go to ``models/<stage>/``: ``model.pt`` (final weights), ``last.pt`` (resumable),
``history.csv`` (per step) and ``summary.json`` (final validation and timing).
"""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

from armpose.config import load_params, project_root
from armpose.distill import resolve_teacher
from armpose.io import atomic_write_json
from armpose.train import train


def run_stage(stage: str, params: dict, root: Path | None = None, after=None) -> dict:
    """Train ``stage`` with ``params``; ``init_from`` and ``distill.teacher`` paths are relative to ``root``.
    ``after(cfg, base, root, out)``, if given, runs once training is done and adds to the summary."""
    root = Path(root or project_root())
    cfg = resolve_teacher(dict(params[stage]), root)
    if cfg["init_from"] not in ("scratch", "resume"):
        cfg["init_from"] = str(root / cfg["init_from"])
    out = root / "models" / stage
    summary = train(stage, cfg, params["base"], root / "data" / "labels", out)
    if after is not None:
        summary.update(after(cfg, params["base"], root, out))
    atomic_write_json(out / "summary.json", summary)
    return {"out": out, **summary}


def stage_main(stage: str, doc: str, argv: list[str] | None = None, after=None) -> None:
    """Command-line entry of a training stage."""
    ap = argparse.ArgumentParser(prog=f"armpose {stage}", description=doc)
    ap.add_argument("--params", default=None, help="params file (default: the project's params.yaml)")
    ap.add_argument("--root", default=None, help="project root holding data/ and models/")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    res = run_stage(stage, load_params(args.params), args.root, after)
    print(f"{stage}: {res['steps']} steps in {res['wall_s']:.0f} s ({res['s_per_step'] * 1000:.0f} ms/step); "
          f"val joint {res.get('val_joint_cm', float('nan')):.1f} cm, base {res.get('val_base_cm', float('nan')):.1f} cm, "
          f"type acc {100 * res.get('val_type_acc', float('nan')):.1f} %, mask acc "
          f"{100 * res.get('val_mask_acc', float('nan')):.1f} %; weights in {res['out'] / 'model.pt'}")


def stage_functions(stage: str, doc: str, after=None):
    """``run(params, root)`` and ``main(argv)`` of training stage ``stage``, for its module;
    ``after`` as in :func:`run_stage`."""
    def run(params: dict, root: Path | None = None) -> dict:
        """Train this stage; returns the output folder and the final validation summary."""
        return run_stage(stage, params, root, after)

    def main(argv: list[str] | None = None) -> None:
        stage_main(stage, doc, argv, after)

    return run, main
