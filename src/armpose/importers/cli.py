"""``armpose import``: turn a raw recording (a folder of images and CSVs, or a ROS bag) into the
armpose recording format.

    armpose import folder SRC OUT --robot ROBOT --intrinsics cam.json [--camera-pose x,y,z,qx,qy,qz,qw]
    armpose import bag BAG OUT --robot ROBOT (--pose-topic TOPIC | --camera-pose x,y,z,qx,qy,qz,qw)
                       [--image-topic TOPIC] [--joint-topic /joint_states] [--camera-info-topic TOPIC]
"""
from __future__ import annotations

import argparse
import json
import logging
import sys

from armpose.importers.common import NothingKeptError, load_transform, parse_pose_text
from armpose.intrinsics import load_intrinsics
from armpose.recording import RecordingError


def _common(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("out", help="recording folder to create (built in a hidden sibling, renamed when complete)")
    ap.add_argument("--robot", required=True, help="robot type (armpose robots)")
    ap.add_argument("--camera-pose", metavar="x,y,z,qx,qy,qz,qw",
                    help="fixed camera optical frame pose in the robot base frame (metres, xyzw; Eye-to-Hand)")
    ap.add_argument("--T-rig-cam", dest="T_rig_cam", metavar="FILE.json|x,y,z,qx,qy,qz,qw",
                    help="camera optical frame in the mocap rig frame (armpose calibrate-rig's JSON)")
    ap.add_argument("--T-world-base", dest="T_world_base", metavar="FILE.json|x,y,z,qx,qy,qz,qw",
                    help="robot base in the mocap world frame (default: they coincide)")
    ap.add_argument("--tolerance-ms", type=float, default=20.0,
                    help="largest image-to-sample time difference for a match (default 20)")
    ap.add_argument("--max-pose-jump-m", type=float, default=0.10,
                    help="camera moves more between consecutive frames: both dropped (default 0.10)")
    ap.add_argument("--max-pose-jump-deg", type=float, default=10.0,
                    help="camera turns more between consecutive frames: both dropped (default 10)")
    ap.add_argument("--ignore-joint", action="append", default=[], metavar="NAME",
                    help="accept and drop this joint name although the URDF lacks it (repeatable)")
    ap.add_argument("--notes", default="", help="free text for recording.json")
    ap.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    ap.add_argument("--json", action="store_true", help="print the summary as JSON")
    ap.add_argument("-v", "--verbose", action="store_true", help="log every dropped frame")


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="armpose import", description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="source", required=True)
    folder = sub.add_parser("folder", help="images/ or images.csv, joint_states.csv, camera_poses.csv")
    folder.add_argument("src", help="the raw folder")
    _common(folder)
    folder.add_argument("--intrinsics", required=True, metavar="cam.json",
                        help="width, height, fx, fy, cx, cy (pixels) of the rectified images")
    folder.add_argument("--time-unit", choices=["s", "ms", "us", "ns"], default="s",
                        help="unit of the timestamps in file names and CSVs (default s)")
    bag = sub.add_parser("bag", help="ROS 1 .bag file or ROS 2 bag folder")
    bag.add_argument("src", help="the bag")
    _common(bag)
    bag.add_argument("--intrinsics", metavar="cam.json", help="instead of the CameraInfo topic")
    bag.add_argument("--image-topic", help="sensor_msgs/Image or CompressedImage (default: the only one)")
    bag.add_argument("--joint-topic", default="/joint_states", help="sensor_msgs/JointState (default /joint_states)")
    bag.add_argument("--pose-topic", help="geometry_msgs/PoseStamped of the mocap rig or camera")
    bag.add_argument("--camera-info-topic", help="sensor_msgs/CameraInfo (default: the only one)")
    bag.add_argument("--stamp", choices=["header", "bag"], default="header",
                     help="match on header.stamp (default) or on the bag's record time")
    return ap


def _options(args: argparse.Namespace) -> dict:
    """Library keyword arguments from the parsed command line (files and poses parsed here)."""
    return {
        "tolerance_ms": args.tolerance_ms, "max_pose_jump_m": args.max_pose_jump_m,
        "max_pose_jump_deg": args.max_pose_jump_deg, "ignore_joints": tuple(args.ignore_joint),
        "camera": load_intrinsics(args.intrinsics) if args.intrinsics else None,
        "camera_pose": parse_pose_text(args.camera_pose, "--camera-pose") if args.camera_pose else None,
        "T_rig_cam": load_transform(args.T_rig_cam, "--T-rig-cam", "T_rig_cam") if args.T_rig_cam else None,
        "T_world_base": (load_transform(args.T_world_base, "--T-world-base", "T_world_base")
                         if args.T_world_base else None),
        "notes": args.notes, "overwrite": args.overwrite, "progress": sys.stderr.isatty(),
    }


def format_summary(s: dict) -> str:
    """The summary dict of an import as a few lines of text."""
    cam, offset = s["camera"], s["max_offset_ms"]
    return "\n".join([
        f"imported {s['kept']} of {s['images']} images from {s['source']} into {s['output']} (robot {s['robot']})",
        "  dropped: " + ", ".join(f"{n} {reason}" for reason, n in s["dropped"].items()),
        "  ignored: " + (", ".join(f"{k} {v}" for k, v in s["ignored"].items()) or "nothing"),
        f"  max time offset: joints {offset['joints']:.1f} ms, pose {offset['pose']:.1f} ms "
        + f"(tolerance {s['tolerance_ms']:g} ms)",
        f"  camera {cam['width']}x{cam['height']} fx {cam['fx']:g} fy {cam['fy']:g} ({s['intrinsics_from']}); "
        + f"camera pose from {s['camera_pose_from']}",
    ])


def _run(args: argparse.Namespace) -> dict:
    opts = _options(args)
    if args.source == "folder":
        from armpose.importers.folder import import_folder
        return import_folder(args.src, args.out, args.robot, time_unit=args.time_unit, **opts)
    from armpose.importers.bag import import_bag
    return import_bag(args.src, args.out, args.robot, image_topic=args.image_topic, joint_topic=args.joint_topic,
                      pose_topic=args.pose_topic, camera_info_topic=args.camera_info_topic, stamp=args.stamp,
                      **opts)


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``armpose import``; returns the exit status (0 ok, 1 bad input)."""
    args = build_parser().parse_args(sys.argv[1:] if argv is None else argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(levelname)s %(message)s")
    from rosbags.highlevel import AnyReaderError
    try:
        summary = _run(args)
    except NothingKeptError as err:
        print(format_summary(err.summary))
        print(f"armpose import: error: {err}", file=sys.stderr)
        return 1
    except (RecordingError, ValueError, FileExistsError, FileNotFoundError, AnyReaderError) as err:
        print(f"armpose import: error: {err}", file=sys.stderr)
        return 1
    print(json.dumps(summary, indent=2) if args.json else format_summary(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
