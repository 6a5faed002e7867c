"""Command line of ``armpose predict`` (see :mod:`armpose.predict` for the output schema).

    armpose predict --checkpoint PATH [--intrinsics cam.json] [--out preds.jsonl]
                    [--masks DIR] [--overlays DIR] [--mirror] [--zoom] IMAGE_OR_DIR...
    armpose predict --sequence [--filter kalman|one-euro|none] [--rate-hz HZ]
                    [--joints JOINTS.csv --robot NAME] --checkpoint PATH [...] FRAMES_DIR_OR_VIDEO...

Writes one JSON object per image, one per line, to ``--out`` (atomically) or stdout. A file
that cannot be read, is not an image or does not match the camera gets one line on stderr
naming it; the others are still processed, and the exit status is 1 if any failed.

``--mirror`` runs each image together with its horizontal mirror and averages the two
estimates (:mod:`armpose.mirror_test`): two images a forward pass, for a more accurate
estimate; ``results/results_table.md`` ("Mirror test") gives both accuracies and latencies.
``--zoom`` takes a second look at the robot found by the first pass, from a camera turned to
it and moved closer (:mod:`armpose.zoom_test`; a network trained with ``augment.zoom`` has seen
such views) and averages the two looks: one more forward pass; "Zoom test" in
the results table gives its accuracy and latency. Both may be given.

``--fit`` fits the predicted robot type's own model (joint angles and pose, forward kinematics of
its description) to the network's estimate, on the rays and, loosely, the depths of its points
(:mod:`armpose.kinematic_fit`): a physically valid robot, plus ``joint_angles`` and
``camera_T_base`` in the output; "Kinematic fit" in the results table gives its accuracy.

``--sequence`` treats the inputs as consecutive frames (folders sorted by file name, videos
read with OpenCV, frame k of ``clip.avi`` named ``clip.avi#k``) and smooths the 3D outputs
causally; see :mod:`armpose.sequence` for the added keys. ``--rate-hz`` defaults to the
video's frame rate, else 30. ``--joints`` (header ``frame`` then the joint names, rows in
frame order; or ``image`` then the joint names, rows naming their frames) adds the camera
pose ``T_cam_base`` per frame and needs ``--robot``.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

import numpy as np

from armpose.extrinsics import match_rows, read_joint_csv
from armpose.intrinsics import IntrinsicsError
from armpose.io import atomic_write_text
from armpose.predict import PredictError, predict, write_overlay
from armpose.recording import RecordingError
from armpose.robots.registry import UnknownRobotError, get_robot
from armpose.sequence import FILTERS, frame_stem, iter_sequence, list_frames

SEQUENCE_ONLY = ("filter", "rate_hz", "joints", "robot")


def write_sequence_overlay(row: dict, image: np.ndarray, mask: np.ndarray | None, folder: Path) -> None:
    """A sequence frame with its mask and smoothed joints drawn on it, ``<frame_stem>_overlay.png``."""
    uv = np.array([[np.nan, np.nan] if p is None else p for p in row["joints_uv"]], dtype=np.float64)
    write_overlay(image, mask, uv, folder, frame_stem(row["image"]))


def sequence_angles(args: argparse.Namespace) -> np.ndarray | None:
    """Joint angles ``(N, J)`` for the N frames of the sequence from ``--joints``, or None."""
    if not args.joints:
        return None
    table = read_joint_csv(args.joints)
    angles = table.angles_for(get_robot(args.robot).joints)
    return angles[match_rows(table, list_frames(args.inputs))]


def run_sequence(args: argparse.Namespace, errors: list[str]) -> None:
    """``--sequence``: lines streamed to stdout, or written at the end to ``--out``."""
    angles = sequence_angles(args)
    lines = []
    for row, image, mask in iter_sequence(args.inputs, args.checkpoint, args.intrinsics, args.filter or "kalman",
                                          args.rate_hz, device=args.device, joint_angles=angles, robot=args.robot,
                                          masks=Path(args.masks) if args.masks else None, errors=errors,
                                          mirror=args.mirror, zoom=args.zoom):
        line = json.dumps(row) + "\n"
        if args.out:
            lines.append(line)
        else:
            sys.stdout.write(line)
            sys.stdout.flush()
        if args.overlays:
            write_sequence_overlay(row, image, mask if args.masks else None, Path(args.overlays))
    if args.out:
        atomic_write_text(Path(args.out), "".join(lines))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="armpose predict", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("inputs", nargs="+", metavar="IMAGE_OR_DIR")
    ap.add_argument("--checkpoint", required=True, help="e.g. models/transfer_stage2/model.pt after dvc repro")
    ap.add_argument("--intrinsics", default=None, help="JSON with width, height, fx, fy, cx, cy of your camera")
    ap.add_argument("--out", default=None, help="JSONL output file (default: stdout)")
    ap.add_argument("--masks", default=None, help="folder for mask PNGs (255 = robot), input size")
    ap.add_argument("--overlays", default=None, help="folder for images with the predicted mask and joints drawn")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--mirror", action="store_true", help="average with the mirrored image's estimate (2 images a forward)")
    ap.add_argument("--zoom", action="store_true", help="a second look from a camera turned to the robot and moved closer")
    ap.add_argument("--fit", action="store_true", help="fit the predicted robot's model to the estimate; adds joint_angles, camera_T_base")
    ap.add_argument("--sequence", action="store_true", help="inputs are consecutive frames (folders, videos)")
    ap.add_argument("--filter", choices=FILTERS, help="causal smoothing of --sequence (default kalman)")
    ap.add_argument("--rate-hz", type=float, help="frames per second of --sequence (default: the video's, else 30)")
    ap.add_argument("--joints", type=Path, help="--sequence: encoder readings (radians) per frame, adds T_cam_base")
    ap.add_argument("--robot", help="--sequence: the robot type (needed with --joints)")
    args = ap.parse_args(argv)
    given = [f"--{k.replace('_', '-')}" for k in SEQUENCE_ONLY if getattr(args, k) is not None]
    if given and not args.sequence:
        ap.error(f"{', '.join(given)} only with --sequence")
    if args.fit and args.sequence:
        ap.error("--fit works on single images, not with --sequence")
    if args.joints and not args.robot:
        ap.error("--joints needs --robot")
    if args.rate_hz is not None and not args.rate_hz > 0:
        ap.error(f"--rate-hz must be positive, got {args.rate_hz}")
    logging.basicConfig(level=logging.CRITICAL)  # failures are printed below, once each
    errors: list[str] = []
    if args.sequence:
        try:
            run_sequence(args, errors)
        except (PredictError, RecordingError, UnknownRobotError, ValueError) as err:
            errors.append(str(err.args[0]) if isinstance(err, UnknownRobotError) else str(err))
        for msg in errors:
            print(f"armpose predict: {msg}", file=sys.stderr)
        return 1 if errors else 0
    try:
        rows = predict(args.inputs, args.checkpoint, args.intrinsics, Path(args.masks) if args.masks else None,
                       args.device, errors=errors, mirror=args.mirror, zoom=args.zoom, fit=args.fit,
                       overlays=Path(args.overlays) if args.overlays else None)
    except (PredictError, IntrinsicsError) as err:
        print(f"armpose predict: {err}", file=sys.stderr)
        return 1
    for msg in errors:
        print(f"armpose predict: {msg}", file=sys.stderr)
    text = "".join(json.dumps(r) + "\n" for r in rows)
    if args.out:
        atomic_write_text(Path(args.out), text)
    else:
        sys.stdout.write(text)
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
