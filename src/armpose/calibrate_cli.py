"""``armpose calibrate``: the pose of a static camera relative to the robot base, from images
and the joint encoder readings at those instants (no calibration board).

    armpose calibrate --checkpoint PATH --joints JOINTS.csv [--intrinsics cam.json] [--robot NAME]
                      [--out extrinsics.json] [--refine-rays | --refine-2d] [--per-image]
                      [--method huber|ransac|lstsq]
                      [--threshold-m 0.05] IMAGE_OR_DIR...

``--refine-rays`` refines the robust fit so that each forward-kinematics point lies on the ray of
its predicted point and near its predicted depth, weighted by the network's typical errors (it
reads directions far better than depth); the results table ("Camera-to-robot pose") compares it
with the rigid fit alone. ``--refine-2d`` refines on the pixels alone instead.

JOINTS.csv: a header ``frame`` or ``image``, then one column per joint of the robot (names as
in ``armpose robots``, any order; radians). With ``frame`` (the recording format's
``joints.csv``), data row k goes with image k, folders expanded in sorted file-name order; with
``image``, each row names its image (path as given, or file name). A bad file, line or value
stops with an error naming them. The robot type is ``--robot``, else the one predicted for most
images.

Output JSON (``--out``, written atomically, else stdout): ``T_cam_base`` (4x4, base frame to
camera optical frame, x right, y down, z forward; metres), ``quaternion_xyzw``,
``translation_m``, the inverse ``T_base_cam`` (camera pose in the base frame, the Eye-to-Hand
transform) with its quaternion and translation, and the residual report: ``rmse_m``,
``reprojection_rmse_px``, ``images_used``, ``points_used``, ``per_point`` (median residual and
inlier fraction), ``per_image`` (residual per point in metres and pixels, outliers, and how far
that image's own fit lies from the result). Exit status 1 if any image could not be used.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
from collections import Counter
from pathlib import Path

from armpose.camera_pose import METHODS
from armpose.extrinsics import estimate_extrinsics, match_rows, read_joint_csv
from armpose.geometry import Camera
from armpose.io import atomic_write_json
from armpose.intrinsics import load_intrinsics
from armpose.predict import PredictError, expand_inputs, predict
from armpose.recording import RecordingError
from armpose.robots.registry import UnknownRobotError, get_robot
from armpose.train import load_checkpoint

PROG = "armpose calibrate"


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("inputs", nargs="+", metavar="IMAGE_OR_DIR", help="images from one static camera")
    ap.add_argument("--checkpoint", required=True, help="e.g. models/transfer_stage2/model.pt after dvc repro")
    ap.add_argument("--joints", required=True, type=Path, help="JOINTS.csv: encoder readings (radians) per image")
    ap.add_argument("--intrinsics", type=Path, help="JSON with width, height, fx, fy, cx, cy of your camera")
    ap.add_argument("--robot", help="robot type (default: the type predicted for most images)")
    ap.add_argument("--out", type=Path, help="result JSON (default: stdout)")
    refine = ap.add_mutually_exclusive_group()
    refine.add_argument("--refine-rays", action="store_true",
                        help="refine the pose on the predicted points' rays and depths (each by its typical error)")
    refine.add_argument("--refine-2d", action="store_true", help="polish the pose on the 2D reprojection error")
    ap.add_argument("--per-image", action="store_true",
                    help="average per-image fits instead of one robust fit of all images' points")
    ap.add_argument("--method", choices=METHODS, default="huber", help="robust fit (default %(default)s)")
    ap.add_argument("--threshold-m", type=float, default=0.05,
                    help="inlier threshold, metres: about 3x the per-point error (default %(default)s)")
    ap.add_argument("--device", default="cpu")
    return ap.parse_args(argv)


def majority_type(rows: list[dict]) -> str:
    """The type predicted for most images; ties go to the larger summed probability."""
    counts = Counter(r["robot_type"] for r in rows)
    mass = Counter()
    for r in rows:
        mass.update(r["type_probs"])
    return max(counts, key=lambda t: (counts[t], mass[t]))


def camera_of(args: argparse.Namespace) -> Camera:
    """The images' camera: ``--intrinsics``, else the checkpoint's canonical camera."""
    if args.intrinsics:
        return load_intrinsics(args.intrinsics)
    return Camera.from_dict(load_checkpoint(Path(args.checkpoint))["config"]["base"]["camera"])


def run(args: argparse.Namespace, errors: list[str]) -> dict:
    """The result dict; raises PredictError, RecordingError or ValueError with a message for the user."""
    table = read_joint_csv(args.joints)
    images = [str(p) for p in expand_inputs(args.inputs)]
    if not images:
        raise PredictError(f"no images in {args.inputs}")
    row_of = dict(zip(images, match_rows(table, images)))
    if args.robot:
        table.angles_for(get_robot(args.robot).joints)        # a header error before the network runs
    camera = camera_of(args)
    preds = predict(images, args.checkpoint, camera, device=args.device, errors=errors)
    if not preds:
        raise PredictError("no image could be read; nothing to calibrate")
    robot = args.robot or majority_type(preds)
    angles = table.angles_for(get_robot(robot).joints)[[row_of[p["image"]] for p in preds]]
    result = estimate_extrinsics(preds, angles, robot, pooled=not args.per_image, method=args.method,
                                 threshold_m=args.threshold_m, refine_2d=args.refine_2d, camera=camera,
                                 refine_rays_depth=args.refine_rays)
    result["inputs"] = {"checkpoint": str(args.checkpoint), "joints": str(args.joints),
                        "intrinsics": str(args.intrinsics) if args.intrinsics else None, "images": len(images),
                        "robot_from": "--robot" if args.robot else "majority of predicted types",
                        "predicted_types": dict(Counter(p["robot_type"] for p in preds))}
    return result


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    errors: list[str] = []
    try:
        result = run(args, errors)
    except (PredictError, RecordingError, UnknownRobotError, ValueError) as err:
        for msg in errors:
            print(f"{PROG}: {msg}", file=sys.stderr)
        print(f"{PROG}: {err.args[0] if isinstance(err, UnknownRobotError) else err}", file=sys.stderr)
        return 1
    for msg in errors:
        print(f"{PROG}: {msg}", file=sys.stderr)
    if args.out:
        atomic_write_json(args.out, result)
        t, r = result["translation_m"], result["rmse_m"]
        print(f"T_cam_base: translation [{t[0]:.4f}, {t[1]:.4f}, {t[2]:.4f}] m, rmse {r} m, "
              f"{result['images_used']} images, {result['points_used']}/{result['points_total']} inlier points "
              f"-> {args.out}")
    else:
        sys.stdout.write(json.dumps(result, indent=1) + "\n")
    return 1 if errors or result["images_skipped"] else 0


if __name__ == "__main__":
    sys.exit(main())
