"""The ``armpose`` command: pipeline stages and tools as subcommands.

    armpose robots                 list the robot registry
    armpose profile NAME           make profiles/NAME.yaml the active params.yaml
    armpose render [...]           stage render (same as python -m armpose.stages.render)
    armpose labels [...]           stage labels (same as python -m armpose.stages.labels)
    armpose pretrain | transfer_stage1 | transfer_stage2 | train_full [...]   training stages
    armpose sweep | latency | evaluate [...]                                 evaluation stages
    armpose predict --checkpoint PATH [--intrinsics cam.json] [--out preds.jsonl]
                    [--masks DIR] [--overlays DIR] IMAGE_OR_DIR...           the network on your images
    armpose import {folder,bag} ...      turn a raw recording into the recording format
    armpose calibrate --checkpoint PATH --joints JOINTS.csv IMAGE...   camera-to-robot pose from images
    armpose calibrate-rig --views DIR --intrinsics cam.json --board board.json --out rig.json
                                         mocap rig to camera optical frame (hand-eye)
"""
from __future__ import annotations

import argparse
import importlib
import sys

STAGES = {name: f"armpose.stages.{name}" for name in
          ("render", "labels", "pretrain", "transfer_stage1", "transfer_stage2", "train_full", "sweep", "latency",
           "evaluate")}
TOOLS = {"predict": "armpose.predict_cli", "import": "armpose.importers.cli", "calibrate-rig": "armpose.calib.cli",
         "calibrate": "armpose.calibrate_cli"}


def cmd_robots(argv: list[str]) -> int:
    argparse.ArgumentParser(prog="armpose robots", description="List the robot registry.").parse_args(argv)
    from armpose.robots import all_robots
    print(f"{'name':<8} {'family':<7} {'joints':>6}  {'base link':<18} urdf")
    for spec in all_robots().values():
        print(f"{spec.name:<8} {spec.family:<7} {spec.num_joints:>6}  {spec.base_link:<18} "
              f"{spec.urdf['source']}:{spec.urdf['path']}")
    return 0


def cmd_profile(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="armpose profile",
                                 description="Write profiles/default.yaml merged with profiles/NAME.yaml to params.yaml.")
    ap.add_argument("name", help="default, quick, paper, or any profiles/*.yaml")
    args = ap.parse_args(argv)
    from armpose.config import select_profile
    print(f"params.yaml now holds profile {args.name!r}: {select_profile(args.name)}")
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    commands = ["robots", "profile", *STAGES, *TOOLS]
    if not argv or argv[0] in ("-h", "--help") or argv[0] not in commands:
        print(__doc__.strip())
        if argv and argv[0] not in ("-h", "--help"):
            print(f"\narmpose: unknown command {argv[0]!r}", file=sys.stderr)
            return 2
        return 0
    cmd, rest = argv[0], argv[1:]
    if cmd == "robots":
        return cmd_robots(rest)
    if cmd == "profile":
        return cmd_profile(rest)
    if cmd in TOOLS:
        return int(importlib.import_module(TOOLS[cmd]).main(rest) or 0)
    importlib.import_module(STAGES[cmd]).main(rest)
    return 0


if __name__ == "__main__":
    sys.exit(main())
