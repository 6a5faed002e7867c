"""Stage ``render``: synthetic recordings of every robot type with PyBullet.

Reads ``params['base']`` and ``params['render']``; writes ``data/render/<robot>/<robot>_NNN/``
recordings. Finished recordings of an identical job are kept, so an interrupted run resumes.
"""
from __future__ import annotations

import argparse
import logging
import shutil
from pathlib import Path

from armpose.config import load_params, project_root
from armpose.parallel import chunks, run_jobs
from armpose.recording import find_recordings
from armpose.sim.render import RenderJob, render_recording

log = logging.getLogger(__name__)


def plan(params: dict, out: Path) -> list[RenderJob]:
    """The render jobs of ``params``: one per recording, each with its own seed."""
    base, cfg = params["base"], params["render"]
    jobs = []
    for r_idx, robot in enumerate(base["robot_types"]):
        total = int(cfg["frames_per_robot"].get(robot, 0))
        for k, count in chunks(total, int(cfg["frames_per_recording"])):
            jobs.append(RenderJob(robot, count, (int(base["seed"]), 1, r_idx, k),
                                  out / robot / f"{robot}_{k:03d}", dict(base["camera"]), cfg,
                                  tuple(base["robot_types"])))
    return jobs


def run(params: dict, root: Path | None = None) -> dict:
    """Render every planned recording not already rendered. Returns paths and counts."""
    root = Path(root or project_root())
    out = root / "data" / "render"
    jobs = plan(params, out)
    wanted = {j.out_dir for j in jobs}
    for stale in find_recordings(out):
        if stale not in wanted:
            log.info("removing stale recording %s", stale)
            shutil.rmtree(stale)
    todo = [j for j in jobs if not j.is_done()]
    for job in todo:
        job.out_dir.parent.mkdir(parents=True, exist_ok=True)
    log.info("render: %d recordings planned, %d to render", len(jobs), len(todo))
    run_jobs(render_recording, todo, int(params["base"]["num_workers"]), weight=lambda j: j.num_frames,
             desc="render")
    return {"out": out, "recordings": [j.out_dir for j in jobs], "frames": sum(j.num_frames for j in jobs),
            "rendered": sum(j.num_frames for j in todo)}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="armpose render", description=__doc__)
    ap.add_argument("--params", default=None, help="params file (default: the project's params.yaml)")
    ap.add_argument("--root", default=None, help="project root where data/ is written")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    res = run(load_params(args.params), args.root)
    print(f"render: {res['frames']} frames in {len(res['recordings'])} recordings under {res['out']} "
          f"({res['rendered']} newly rendered)")


if __name__ == "__main__":
    main()
