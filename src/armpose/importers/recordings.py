"""Existing recordings (a user's real ones) validated and linked into the pipeline's data folder.

Used by the ``record`` stage when ``record.recordings_dir`` names a folder: every recording under
it (a folder holding ``recording.json``, see :mod:`armpose.recording`) is checked completely
before any is linked, and a bad one stops the stage with a
:class:`~armpose.recording.RecordingError` naming the file, the row and the value. Each is then
linked to ``<out>/<robot>/<name>/``: hard links where the file system allows (no copy, no extra
space), copies otherwise; the output's ``recording.json`` is a rewritten copy that adds a
``record_import`` key (source folder, link mode, signature of the source files). A recording is
built in a hidden sibling folder and renamed into place, so it is never half-written; one already
linked from unchanged source files is skipped.
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import tempfile
from pathlib import Path

from armpose.io import atomic_write_json
from armpose.recording import (
    RecordingError,
    find_recordings,
    read_frame,
    read_joints,
    read_meta,
    read_poses,
)

log = logging.getLogger(__name__)


def validate_recording(rec_dir: Path, robot_types) -> dict:
    """Check a recorded recording completely: ``recording.json`` (robot type among ``robot_types``,
    source ``recorded``), every row of ``joints.csv`` and ``camera_poses.csv``, the same frames in
    both, and every frame image (present, readable, the camera's size). Raises the first problem
    as :class:`RecordingError`; returns ``{"robot", "frames"}``."""
    rec_dir = Path(rec_dir)
    meta, spec = read_meta(rec_dir)
    meta_path = rec_dir / "recording.json"
    if meta.source != "recorded":
        raise RecordingError(meta_path, None, meta.source, "record.recordings_dir is for recorded data: "
                             "source must be 'recorded' (synthetic recordings belong in data/render)")
    if meta.robot not in robot_types:
        raise RecordingError(meta_path, None, meta.robot, f"robot type is not in base.robot_types {list(robot_types)}")
    jf, _, jerr = read_joints(rec_dir, spec)
    pf, _, perr = read_poses(rec_dir)
    if jerr or perr:
        raise (jerr + perr)[0]
    for path, frames in ((rec_dir / "joints.csv", jf), (rec_dir / "camera_poses.csv", pf)):
        if not len(frames):
            raise RecordingError(path, None, 0, "no rows: a recording needs at least one frame")
    for f in sorted(set(jf) - set(pf)):
        raise RecordingError(rec_dir / "camera_poses.csv", None, int(f), "no camera pose for frame")
    for f in sorted(set(pf) - set(jf)):
        raise RecordingError(rec_dir / "joints.csv", None, int(f), "no joint reading for frame")
    for f in jf:
        read_frame(rec_dir, int(f), meta.camera)
    return {"robot": meta.robot, "frames": len(jf)}


def _files(rec_dir: Path) -> list[Path]:
    """The recording's files, relative, sorted; hidden files and folders left out."""
    return sorted(p.relative_to(rec_dir) for p in rec_dir.rglob("*")
                  if p.is_file() and not any(part.startswith(".") for part in p.relative_to(rec_dir).parts))


def source_signature(rec_dir: Path) -> str:
    """A hash of the recording's file names, sizes and modification times."""
    h = hashlib.sha1()
    for rel in _files(rec_dir):
        st = (rec_dir / rel).stat()
        h.update(f"{rel}:{st.st_size}:{st.st_mtime_ns}\n".encode())
    return h.hexdigest()[:16]


def _link_or_copy(src: Path, dst: Path) -> str:
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.link(src, dst)
        return "hard link"
    except OSError:  # another file system, or links not allowed
        shutil.copy2(src, dst)
        return "copy"


def link_recording(src: Path, dst: Path) -> str:
    """Link (or copy) recording ``src`` to ``dst`` atomically; returns the link mode."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{dst.name}.", dir=dst.parent))
    try:
        modes = {_link_or_copy(src / rel, tmp / rel) for rel in _files(src) if rel != Path("recording.json")}
        mode = "copy" if "copy" in modes else "hard link"
        meta = json.loads((src / "recording.json").read_text())
        meta["record_import"] = {"from": str(src.resolve()), "mode": mode, "signature": source_signature(src)}
        atomic_write_json(tmp / "recording.json", meta)  # last: its presence marks a finished recording
        if dst.exists():
            shutil.rmtree(dst)
        tmp.rename(dst)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)
    return mode


def is_linked(src: Path, dst: Path) -> bool:
    """True if ``dst`` is a finished link of ``src`` as it is now."""
    meta = dst / "recording.json"
    if not meta.exists():
        return False
    return json.loads(meta.read_text()).get("record_import", {}).get("signature") == source_signature(src)


def link_recordings(src_root: Path, out: Path, robot_types) -> tuple[list[Path], int]:
    """Validate every recording under ``src_root``, then link each to ``out/<robot>/<name>``
    (``name``: its path below ``src_root``, ``/`` written ``__``). Returns the output folders and how
    many were linked now (the rest were up to date)."""
    src_root = Path(src_root)
    recs = find_recordings(src_root)
    if not recs:
        raise FileNotFoundError(f"{src_root}: no recordings there (folders holding recording.json)")
    infos = [validate_recording(r, robot_types) for r in recs]
    log.info("%d recordings under %s are valid (%d frames)", len(recs), src_root, sum(i["frames"] for i in infos))
    dsts = [Path(out) / info["robot"] / ("__".join(rec.relative_to(src_root).parts) or rec.name)
            for rec, info in zip(recs, infos)]
    first: dict[Path, Path] = {}
    for rec, dst in zip(recs, dsts):
        if dst in first:
            raise RecordingError(rec / "recording.json", None, str(dst),
                                 f"would be linked to the same folder as {first[dst]}; rename one of the two")
        first[dst] = rec
    linked = 0
    for rec, dst in zip(recs, dsts):
        if not is_linked(rec, dst):
            log.info("linking %s -> %s (%s)", rec, dst, link_recording(rec, dst))
            linked += 1
    return dsts, linked
