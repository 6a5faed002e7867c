"""Stage ``record``: recordings of a free-moving, mocap-tracked camera (the recorded-data path).

Reads ``params['base']`` and ``params['record']``; writes ``data/record/<robot>/<name>/``
recordings (source ``recorded``) and ``data/record/summary.json``.

- ``record.recordings_dir: null``: simulate ``sessions_per_robot`` sessions per robot type
  (:mod:`armpose.sessions.session`: handheld camera, moving robot, rig calibration and mocap noise),
  named ``<robot>_sNN``, and ``tripod_sessions_per_robot`` static-camera sessions (the camera on a
  tripod, the robot moving: the calibration-free use case), named ``<robot>_tNN``. A finished
  session of an identical job is kept, so a run resumes.
- ``record.recordings_dir: <folder>`` (relative to the project root, or absolute): validate every
  recording there and hard-link (or copy) it in instead (:mod:`armpose.importers.recordings`).

Recordings no longer planned, and hidden temporary folders of an interrupted run, are removed.
"""
from __future__ import annotations

import argparse
import json
import logging
import shutil
from pathlib import Path

import numpy as np

from armpose.config import load_params, project_root
from armpose.importers.recordings import link_recordings
from armpose.io import atomic_write_json
from armpose.parallel import run_jobs
from armpose.recording import find_recordings
from armpose.sessions.session import SessionJob, record_session

log = logging.getLogger(__name__)
STAGE_SEED = 5  # second entry of every session seed: the stage's own stream


#: session kind -> (``params['record']`` key of the sessions per robot, name letter, extra seed entries)
KIND_PLAN = {"handheld": ("sessions_per_robot", "s", ()), "tripod": ("tripod_sessions_per_robot", "t", (1,))}


def plan(params: dict, out: Path) -> list[SessionJob]:
    """The simulated sessions of ``params``: one job per recording, each with its own seed
    (handheld ``(seed, 5, robot index, k)``, tripod ``(seed, 5, robot index, k, 1)``)."""
    base, cfg = params["base"], params["record"]
    jobs = []
    for kind, (key, letter, extra) in KIND_PLAN.items():
        counts = cfg.get(key) or {}
        unknown = sorted(set(counts) - set(base["robot_types"]))
        if unknown:
            raise ValueError(f"record.{key} names {unknown}, not in base.robot_types {base['robot_types']}")
        jobs += [SessionJob(robot, int(cfg["frames_per_session"]), (int(base["seed"]), STAGE_SEED, r_idx, k, *extra),
                            out / robot / f"{robot}_{letter}{k:02d}", dict(base["camera"]), cfg,
                            tuple(base["robot_types"]), kind)
                 for r_idx, robot in enumerate(base["robot_types"]) for k in range(int(counts.get(robot, 0)))]
    return jobs


def _clean(out: Path, wanted: set[Path]) -> None:
    """Remove recordings not in ``wanted`` and hidden leftovers of interrupted runs."""
    for stale in find_recordings(out):
        if stale not in wanted:
            log.info("removing stale recording %s", stale)
            shutil.rmtree(stale)
    for tmp in out.glob("*/.*"):
        if tmp.is_dir():
            shutil.rmtree(tmp)


def session_entry(rec_dir: Path, out: Path) -> dict:
    """One recording's line of ``summary.json``: frames, calibration and (simulated) errors."""
    meta = json.loads((rec_dir / "recording.json").read_text())
    cal, sim = meta.get("rig_calibration"), meta.get("simulation", {})
    return {"name": str(rec_dir.relative_to(out)), "robot": meta["robot"],
            "kind": meta.get("session", {}).get("kind"),
            "frames": len(list((rec_dir / "frames").glob("*.png"))), "simulated": bool(meta.get("simulated")),
            "calibration": None if cal is None else {k: cal[k] for k in ("views_given", "views_used",
                                                                         "rms_reprojection_px", "predicted_std")},
            "rig_offset_error": sim.get("rig_offset_error"), "label_error": sim.get("label_error")}


def write_summary(out: Path, recs: list[Path], recordings_dir: str | None) -> dict:
    """Write ``out/summary.json``: every recording's entry, totals, calibration error statistics."""
    sessions = [session_entry(r, out) for r in recs]
    errs = [s["rig_offset_error"] for s in sessions if s["rig_offset_error"]]
    stats = {k: {"median": float(np.median([e[k] for e in errs])), "max": float(np.max([e[k] for e in errs]))}
             for k in ("translation_mm", "rotation_deg")} if errs else None
    summary = {"mode": "linked" if recordings_dir else "simulated", "recordings_dir": recordings_dir,
               "num_sessions": len(sessions), "num_frames": sum(s["frames"] for s in sessions),
               "rig_offset_error": stats, "sessions": sessions}
    atomic_write_json(out / "summary.json", summary)
    return summary


def run(params: dict, root: Path | None = None) -> dict:
    """Simulate (or link) every recording; returns paths, counts and the summary."""
    root = Path(root or project_root())
    base, cfg = params["base"], params["record"]
    out = root / "data" / "record"
    out.mkdir(parents=True, exist_ok=True)
    src = cfg.get("recordings_dir")
    if src:
        src_path = Path(src) if Path(src).is_absolute() else root / src
        recs, new = link_recordings(src_path, out, base["robot_types"])
        _clean(out, set(recs))
    else:
        jobs = plan(params, out)
        recs = [j.out_dir for j in jobs]
        _clean(out, set(recs))
        todo = [j for j in jobs if not j.is_done()]
        for job in todo:
            job.out_dir.parent.mkdir(parents=True, exist_ok=True)
        log.info("record: %d sessions planned, %d to simulate", len(jobs), len(todo))
        run_jobs(record_session, todo, int(base["num_workers"]), weight=lambda j: j.num_frames, desc="record")
        new = len(todo)
    summary = write_summary(out, recs, str(src) if src else None)
    return {"out": out, "recordings": recs, "frames": summary["num_frames"], "new": new, "summary": summary}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="armpose record", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--params", default=None, help="params file (default: the project's params.yaml)")
    ap.add_argument("--root", default=None, help="project root where data/ is written")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    res = run(load_params(args.params), args.root)
    s = res["summary"]
    print(f"record ({s['mode']}): {res['frames']} frames in {len(res['recordings'])} recordings under {res['out']} "
          f"({res['new']} new)")
    if s["rig_offset_error"]:
        e = s["rig_offset_error"]
        print(f"rig calibration error: median {e['translation_mm']['median']:.2f} mm, "
              f"{e['rotation_deg']['median']:.3f} deg; worst {e['translation_mm']['max']:.2f} mm, "
              f"{e['rotation_deg']['max']:.3f} deg")


if __name__ == "__main__":
    main()
