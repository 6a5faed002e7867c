"""Stage ``labels``: label every recording (synthetic or recorded) and build the dataset.

Reads ``params['base']`` and ``params['labels']``; writes ``data/labels/`` (see
:mod:`armpose.labels.dataset`). Per-recording results are cached in ``data/.cache/labels``
by content, so an interrupted run resumes and unchanged recordings are not labelled twice.

Split: synthetic recordings per frame (:func:`~armpose.labels.dataset.split_for`); recorded ones
per recording (:func:`~armpose.labels.dataset.recorded_test_names`: every static-camera recording
is test, and every robot type gets moving-camera test recordings). ``index.json`` marks each
recording's ``static_camera``.
"""
from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import logging
from pathlib import Path

import numpy as np

from armpose.config import load_params, project_root
from armpose.io import atomic_write_bytes
from armpose.labels.compute import label_recording
from armpose.labels.dataset import SOURCE_CODES, recorded_test_names, split_for, write_dataset
from armpose.labels.quality import joints_near_mask
from armpose.parallel import run_jobs
from armpose.recording import find_recordings, static_camera

log = logging.getLogger(__name__)
LABEL_VERSION = 1


@dataclasses.dataclass(frozen=True)
class LabelJob:
    rec_dir: Path
    cache: Path
    input_size: dict
    max_joints: int
    skip_bad: bool


def recording_digest(rec_dir: Path, settings: dict) -> str:
    """A hash of the recording's tables, its frames' sizes and times, and the label settings."""
    h = hashlib.sha1(json.dumps([LABEL_VERSION, settings], sort_keys=True).encode())
    for name in ("recording.json", "joints.csv", "camera_poses.csv"):
        path = rec_dir / name
        h.update(path.read_bytes() if path.exists() else b"-")
    frames = rec_dir / "frames"
    for f in sorted(frames.glob("*")) if frames.exists() else []:
        st = f.stat()
        h.update(f"{f.name}:{st.st_size}:{st.st_mtime_ns}".encode())
    return h.hexdigest()[:20]


def _label_job(job: LabelJob) -> dict:
    """Label one recording into its cache file (skipped if already there). Returns a summary."""
    if not job.cache.exists():
        arrays, meta, skipped = label_recording(job.rec_dir, job.input_size, job.max_joints, job.skip_bad)
        import io
        buf = io.BytesIO()
        np.savez(buf, **arrays, _meta=np.array(json.dumps({**meta.to_dict(), "skipped": skipped})))
        atomic_write_bytes(job.cache, buf.getvalue())
    with np.load(job.cache) as npz:
        info = json.loads(str(npz["_meta"]))
        return {"frames": int(npz["frame"].shape[0]), **info}


def run(params: dict, root: Path | None = None) -> dict:
    """Label all recordings under ``params['labels']['recordings']`` into ``data/labels``."""
    root = Path(root or project_root())
    base, cfg = params["base"], params["labels"]
    recs = [r for folder in cfg["recordings"] for r in find_recordings(root / folder)]
    if not recs:
        raise FileNotFoundError(f"no recordings under {[str(root / f) for f in cfg['recordings']]}")
    cache_dir = root / "data" / ".cache" / "labels"
    settings = {"input_size": base["input_size"], "max_joints": base["max_joints"], "skip_bad": cfg["skip_bad"]}
    jobs = [LabelJob(r, cache_dir / f"{recording_digest(r, settings)}.npz", base["input_size"],
                     int(base["max_joints"]), bool(cfg["skip_bad"])) for r in recs]
    sizes = {j.rec_dir: len(list((j.rec_dir / "frames").glob("*.png"))) for j in jobs}
    summaries = run_jobs(_label_job, jobs, int(base["num_workers"]), weight=lambda j: sizes[j.rec_dir],
                         desc="labels")
    names = [str(j.rec_dir.relative_to(root)) if j.rec_dir.is_relative_to(root) else str(j.rec_dir) for j in jobs]
    static = [summ["source"] == "recorded" and static_camera(job.rec_dir) for job, summ in zip(jobs, summaries)]
    recorded_test = recorded_test_names(
        [{"name": name, "robot": summ["robot"], "static_camera": st}
         for name, summ, st in zip(names, summaries, static) if summ["source"] == "recorded"],
        int(base["seed"]), float(cfg["test_fraction"]))
    parts, index_recs, skipped = [], [], []
    for k, (job, summ, name) in enumerate(zip(jobs, summaries, names)):
        if summ["robot"] not in base["robot_types"]:
            raise ValueError(f"{job.rec_dir}: robot {summ['robot']!r} is not in base.robot_types "
                             f"{base['robot_types']}")
        with np.load(job.cache) as npz:
            part = {key: npz[key] for key in npz.files if key != "_meta"}
        n = summ["frames"]
        part.update(robot=np.full(n, base["robot_types"].index(summ["robot"]), np.int64),
                    recording=np.full(n, k, np.int64), source=np.full(n, SOURCE_CODES[summ["source"]], np.uint8),
                    split=(np.full(n, int(name in recorded_test), np.uint8) if summ["source"] == "recorded" else
                           split_for(name, n, int(base["seed"]), float(cfg["test_fraction"]))))
        parts.append(part)
        index_recs.append({"name": name, "robot": summ["robot"], "source": summ["source"], "frames": n,
                           "static_camera": static[k]})
        skipped += summ["skipped"]
    split = np.concatenate([p["split"] for p in parts])
    on_mask = np.concatenate([joints_near_mask(p["masks"], p["joints"], p["joint_valid"], p["intrinsics"])
                              for p in parts])
    index = {"robot_types": base["robot_types"], "max_joints": base["max_joints"],
             "input_size": base["input_size"], "recordings": index_recs, "num_frames": int(split.size),
             "num_train": int((split == 0).sum()), "num_test": int((split == 1).sum()),
             "joints_on_mask_fraction": float(on_mask.mean()) if on_mask.size else None,
             "num_skipped": len(skipped), "skipped": skipped}
    if on_mask.size and on_mask.mean() < 0.99:
        log.warning("only %.1f %% of frames have every projected joint within 3 px of the mask: "
                    "check camera poses and joint names", 100 * on_mask.mean())
    out = root / "data" / "labels"
    write_dataset(out, parts, index)
    used = {j.cache for j in jobs}
    for stale in cache_dir.glob("*.npz"):
        if stale not in used:
            stale.unlink()
    return {"out": out, "frames": index["num_frames"], "skipped": len(skipped), "index": index}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="armpose labels", description=__doc__)
    ap.add_argument("--params", default=None, help="params file (default: the project's params.yaml)")
    ap.add_argument("--root", default=None, help="project root holding data/")
    ap.add_argument("--skip-bad", action="store_true", help="skip bad frames (log and count them) instead of stopping; a recording whose header or robot is unusable still stops the run")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    params = load_params(args.params)
    if args.skip_bad:
        params["labels"]["skip_bad"] = True
    res = run(params, args.root)
    print(f"labels: {res['frames']} frames ({res['index']['num_train']} train, {res['index']['num_test']} test) "
          f"in {res['out']}; {res['skipped']} bad frames skipped")


if __name__ == "__main__":
    main()
