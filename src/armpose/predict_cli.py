"""Command line of ``armpose predict`` (see :mod:`armpose.predict` for the output schema).

    armpose predict --checkpoint PATH [--intrinsics cam.json] [--out preds.jsonl]
                    [--masks DIR] [--overlays DIR] IMAGE_OR_DIR...

Writes one JSON object per image, one per line, to ``--out`` (atomically) or stdout. A file
that cannot be read, is not an image or does not match the camera gets one line on stderr
naming it; the others are still processed, and the exit status is 1 if any failed.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

import cv2
import numpy as np

from armpose.io import atomic_write_bytes, atomic_write_text
from armpose.predict import PredictError, predict, read_image
from armpose.viz import overlay_labels


def write_overlay(row: dict, folder: Path) -> None:
    """The input image with its mask (if written) and predicted joints drawn on it."""
    image = read_image(Path(row["image"]))
    mask = cv2.imread(row["mask"], cv2.IMREAD_GRAYSCALE) if "mask" in row else None
    drawn = overlay_labels(image, mask, np.asarray(row["joints_uv"]))
    ok, buf = cv2.imencode(".png", cv2.cvtColor(drawn, cv2.COLOR_RGB2BGR))
    atomic_write_bytes(Path(folder) / f"{Path(row['image']).stem}_overlay.png", buf.tobytes())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="armpose predict", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("inputs", nargs="+", metavar="IMAGE_OR_DIR")
    ap.add_argument("--checkpoint", required=True, help="e.g. models/transfer_stage2/model.pt after dvc repro")
    ap.add_argument("--intrinsics", default=None, help="JSON with width, height, fx, fy, cx, cy of your camera")
    ap.add_argument("--out", default=None, help="JSONL output file (default: stdout)")
    ap.add_argument("--masks", default=None, help="folder for mask PNGs (255 = robot), input size")
    ap.add_argument("--overlays", default=None, help="folder for images with the predictions drawn")
    ap.add_argument("--device", default="cpu")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.CRITICAL)  # failures are printed below, once each
    errors: list[str] = []
    try:
        rows = predict(args.inputs, args.checkpoint, args.intrinsics, Path(args.masks) if args.masks else None,
                       args.device, errors=errors)
    except PredictError as err:
        print(f"armpose predict: {err}", file=sys.stderr)
        return 1
    for msg in errors:
        print(f"armpose predict: {msg}", file=sys.stderr)
    text = "".join(json.dumps(r) + "\n" for r in rows)
    if args.out:
        atomic_write_text(Path(args.out), text)
    else:
        sys.stdout.write(text)
    if args.overlays:
        for row in rows:
            write_overlay(row, Path(args.overlays))
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
