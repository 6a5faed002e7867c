"""``armpose calibrate-rig``: the mocap-rig-to-camera transform ``T_rig_cam`` from ChArUco board views.

    armpose calibrate-rig --views DIR --intrinsics cam.json --board board.json --out rig.json
    armpose calibrate-rig --simulate DIR [--seed N]      write a simulated session to try it on

Input layout: :mod:`armpose.calib.views`. Output JSON (written atomically): ``T_rig_cam`` (4x4,
maps camera optical frame points, x right, y down, z forward, to the rig body frame; metres),
``translation``, ``quaternion_xyzw``, per-view residuals (rotation deg, translation mm,
reprojection px, status used / rejected / no_board), ``rejected`` views and the uncertainty the
noise model predicts. Method: :mod:`armpose.calib.rig`.
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from armpose.calib.rig import OUTLIER_K, RigSettings, calibrate_rig
from armpose.calib.solve import MocapNoise
from armpose.calib.views import load_views, read_board, write_session
from armpose.intrinsics import read_intrinsics
from armpose.io import atomic_write_json

PROG = "armpose calibrate-rig"


def parse_args(argv: list[str]) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog=PROG, description="The mocap-rig-to-camera transform T_rig_cam "
                                 "(camera optical frame to rig body frame) from ChArUco board views.",
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="Input layout:\n" + _layout_help())
    ap.add_argument("--views", type=Path, help="folder with the images, rig_poses.csv and board_poses.csv")
    ap.add_argument("--intrinsics", type=Path, help="cam.json: width, height, fx, fy, cx, cy [, distortion]")
    ap.add_argument("--board", type=Path, help="board.json: squares_x, squares_y, square_length, marker_length")
    ap.add_argument("--out", type=Path, help="result JSON (rig.json)")
    ap.add_argument("--pixel-sigma", type=float, default=RigSettings.pixel_sigma,
                    help="corner noise, px per coordinate (default %(default)s)")
    ap.add_argument("--mocap-translation-mm", type=float, default=MocapNoise.translation_mm,
                    help="RMS mocap position error, mm (default %(default)s)")
    ap.add_argument("--mocap-rotation-deg", type=float, default=MocapNoise.rotation_deg,
                    help="RMS mocap rotation error, degrees (default %(default)s)")
    ap.add_argument("--outlier-k", type=float, default=OUTLIER_K,
                    help="reject views above median + k * 1.4826 MAD of a residual (default %(default)s)")
    ap.add_argument("--simulate", type=Path, metavar="DIR", help="write a simulated session to DIR and stop")
    ap.add_argument("--seed", type=int, default=0, help="seed of --simulate (default %(default)s)")
    args = ap.parse_args(argv)
    if args.simulate is None:
        missing = [f"--{k}" for k in ("views", "intrinsics", "board", "out") if getattr(args, k) is None]
        if missing:
            ap.error(f"missing {', '.join(missing)}")
    return args


def _layout_help() -> str:
    from armpose.calib import views
    doc = views.__doc__
    return doc[doc.index("Layout::") + len("Layout::"):doc.index("Positions in metres")].rstrip() + "\n"


def _print_result(result: dict) -> None:
    print(f"{'image':<24} {'status':<9} {'corners':>7} {'rot deg':>8} {'trans mm':>9} {'reproj px':>9}")
    for v in result["views"]:
        nums = [f"{v[k]:>{w}.3f}" if v[k] is not None else f"{'-':>{w}}"
                for k, w in (("rotation_deg", 8), ("translation_mm", 9), ("reprojection_px", 9))]
        print(f"{v['name']:<24} {v['status']:<9} {v['corners']:>7} {' '.join(nums)}")
    t, q = result["translation"], result["quaternion_xyzw"]
    std = result["predicted_std"]
    print(f"\nT_rig_cam from {result['views_used']} of {result['views_given']} views "
          f"(rejected: {', '.join(result['rejected']) or 'none'}); "
          f"RMS reprojection {result['rms_reprojection_px']:.3f} px")
    print(f"  translation m  {t[0]:+.5f} {t[1]:+.5f} {t[2]:+.5f}")
    print(f"  quaternion xyzw {q[0]:+.6f} {q[1]:+.6f} {q[2]:+.6f} {q[3]:+.6f}")
    if std["rotation_deg"] is not None:
        print(f"  predicted 1-sigma: {std['rotation_deg']:.3f} deg, {std['translation_mm']:.2f} mm")


def main(argv: list[str] | None = None) -> int:
    """Run the command; returns the exit status (1 for bad input or too few usable views)."""
    args = parse_args(list(sys.argv[1:] if argv is None else argv))
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    if args.simulate is not None:
        from armpose.calib.simulate import simulate_session
        paths = write_session(simulate_session(args.seed), args.simulate)
        print(f"simulated session (seed {args.seed}) in {args.simulate}: " + ", ".join(str(p) for p in paths.values()))
        return 0
    settings = RigSettings(MocapNoise(args.mocap_translation_mm, args.mocap_rotation_deg), args.pixel_sigma,
                           args.outlier_k)
    try:
        camera, distortion = read_intrinsics(args.intrinsics)
        board = read_board(args.board)
        views = load_views(args.views, camera, board, distortion)
        calib = calibrate_rig(views, camera, board.center, settings)
    except ValueError as err:
        print(f"{PROG}: error: {err}", file=sys.stderr)
        return 1
    result = calib.to_dict()
    result["inputs"] = {"views": str(args.views), "intrinsics": camera.to_dict(),
                        "distortion": None if distortion is None else distortion.tolist(),
                        "board": board.to_dict(),
                        "settings": {"pixel_sigma": args.pixel_sigma, "mocap_translation_mm": args.mocap_translation_mm,
                                     "mocap_rotation_deg": args.mocap_rotation_deg, "outlier_k": args.outlier_k}}
    atomic_write_json(args.out, result)
    _print_result(result)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
