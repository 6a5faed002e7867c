"""The command line that the post-hoc checkpoint benchmarks share (``bone_rescale.py``,
``ray_bone_fit.py``, ``pose_fit_sigmas.py``): ``[CHECKPOINT] [--out FILE] [--threads N]``."""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

import torch

from armpose.config import project_root
from armpose.inference import load_inference_model


def load_checkpoint_from_cli(doc: str, extra=None) -> tuple[argparse.Namespace, Path, torch.nn.Module, dict]:
    """Parse the shared arguments (help text ``doc``; ``extra(parser)`` adds a script's own), set
    the torch threads and load the checkpoint (default: the two-stage transfer model). Returns
    ``(args, root, model, config)``."""
    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint", nargs="?", type=Path, default=Path("models/transfer_stage2/model.pt"))
    ap.add_argument("--out", type=Path, help="also write the JSON here (atomically)")
    ap.add_argument("--threads", type=int, default=2)
    if extra is not None:
        extra(ap)
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    root = project_root()
    torch.set_num_threads(args.threads)
    model, config = load_inference_model(root / args.checkpoint)
    return args, root, model, config
