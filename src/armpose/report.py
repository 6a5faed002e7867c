"""The results table (paper Table II side by side with ours) and the run's environment record.

The paper's numbers are quoted from Miseikis et al. 2019, Table II ("Summary of the Transfer
Learning results (using 500 samples of each robot type for training) on the test set"),
measured on real camera images. Ours come from ``results/metrics.json`` of the last run,
measured on the held-out split of our data (synthetic renders unless recorded data is added).
"""
from __future__ import annotations

import json
import os
import platform
import subprocess
from importlib import metadata
from pathlib import Path
from typing import Mapping

from armpose.camera_pose import LOG_DEPTH_SIGMA, RAY_SIGMA

PAPER_TABLE_II = {
    "UR": {"mask_accuracy": 0.970, "type_accuracy": 0.975, "joint_median_cm": 3.12, "base_median_cm": 2.42},
    "KUKA": {"mask_accuracy": 0.977, "type_accuracy": 1.000, "joint_median_cm": 3.30, "base_median_cm": 2.36},
    "Panda": {"mask_accuracy": 0.943, "type_accuracy": 0.961, "joint_median_cm": 3.64, "base_median_cm": 3.01},
}
PAPER_LATENCY_MS = (19, 23)
HIGHER_IS_BETTER = {"mask_accuracy": True, "type_accuracy": True, "joint_median_cm": False, "base_median_cm": False}
ROW_NAMES = {"mask_accuracy": "Mask accuracy, %", "type_accuracy": "Robot type accuracy, %",
             "joint_median_cm": "Joint position error (median), cm", "base_median_cm": "Base position error (median), cm"}
MEASURES_NOTE = (
    "How the measures are computed (`armpose.metrics.summarise`): mask accuracy and IoU per frame, in "
    "network-input pixels (256x212), then averaged over the frames; joint errors on the true type's joints "
    "(6 for UR, 7 for iiwa and Panda), also where the type is predicted wrong, and the joint median and mean "
    "pooled over every joint of every frame; base errors per frame. `add_auc_10cm`: the area under the "
    "fraction of frames whose mean joint error is below t, for t from 0 to 10 cm, 1 for a perfect estimate "
    "(NVlabs/DREAM's ADD AUC); `pck_5px` and `pck_10px`: the fraction of joints whose projection is within "
    "5 and 10 pixels of the canonical 480x360 camera (each frame's error scaled by its network-input focal "
    "length over the canonical one).")
PACKAGES = ("torch", "numpy", "pybullet", "pytorch-kinematics", "opencv-python-headless", "dvc", "matplotlib")


def _fmt(key: str, value: float) -> str:
    if value != value:  # NaN
        return "n/a"
    return f"{100 * value:.1f}" if key in ("mask_accuracy", "type_accuracy") else f"{value:.2f}"


def beats_paper(ours: Mapping, family: str, key: str) -> bool:
    paper = PAPER_TABLE_II[family][key]
    return ours[key] >= paper if HIGHER_IS_BETTER[key] else ours[key] <= paper


def headline_metrics(test: Mapping, headline: str) -> Mapping:
    """The per-family metrics the headline table reports: the single pass (``single``) or a
    test-time option of :data:`PASS_OPTIONS` that the evaluate stage ran."""
    if headline == "single":
        return test["by_family"]
    if headline not in PASS_OPTIONS:
        raise ValueError(f"evaluate.headline must be 'single' or one of {sorted(PASS_OPTIONS)}, got {headline!r}")
    if headline not in test:
        raise ValueError(f"evaluate.headline is {headline!r} but the evaluate stage did not run it "
                         f"(evaluate.{headline}: true)")
    return test[headline]["by_family"]


def headline_caption(headline: str, latency: Mapping, section: Mapping | None = None) -> str:
    """What the headline table's "ours" column is, with its batch-1 latency when measured;
    ``section``: the headline variant's metrics (:func:`pass_option`)."""
    cpu = latency.get("cpu", {})
    if headline == "single":
        ms = cpu.get("batch1_median_ms")
        return "one forward pass" + (f" ({ms:.1f} ms per frame at batch 1 on this CPU)" if ms else "")
    title, short, _, phrase = pass_option(headline, section or {})
    ms = cpu.get(f"{short}_batch1_median_ms")
    return f"with {phrase} (section \"{title}\" below" + (f"; {ms:.1f} ms per frame at batch 1 on this CPU)" if ms else ")")


def results_table(metrics: Mapping, data_note: str, headline: str = "single") -> str:
    """Markdown: the paper's Table II and ours (two-stage transfer, and full training) per family,
    extra metrics, latency, and notes on what is still short of the paper. ``headline``: which
    of our variants the first table reports (:func:`headline_metrics`); the single pass is always
    in the option sections beside each variant."""
    test = metrics["transfer"]["test"]
    chosen = headline_metrics(test, headline)
    fams = [f for f in PAPER_TABLE_II if f in chosen]
    ours = {f: chosen[f] for f in fams}
    single = {f: test["by_family"][f] for f in fams}
    full = metrics.get("train_full", {}).get("test", {}).get("by_family", {})
    head = "| Measure | " + " | ".join(f"{f} paper | {f} ours" for f in fams) + " |"
    lines = [head, "|---|" + "---:|---:|" * len(fams)]
    short = []
    for key, name in ROW_NAMES.items():
        cells = []
        for f in fams:
            mark = "**" if beats_paper(ours[f], f, key) else ""
            cells += [_fmt(key, PAPER_TABLE_II[f][key]), f"{mark}{_fmt(key, ours[f][key])}{mark}"]
            if not beats_paper(ours[f], f, key):
                short.append(f"{f} {name.split(',')[0].lower()}: {_fmt(key, ours[f][key])} against the paper's "
                             f"{_fmt(key, PAPER_TABLE_II[f][key])}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    out = ["# Results: paper Table II and ours", "",
           f"Paper: real camera images (Miseikis et al. 2019, Table II). Ours: {data_note}", "",
           "Two-stage transfer model (`models/transfer_stage2/model.pt`), held-out test split, "
           f"{headline_caption(headline, metrics.get('latency', {}), test.get(headline))}. "
           "Bold: ours at least as good as the paper's.", "", *lines, "", MEASURES_NOTE, ""]
    extra_keys = ("mask_iou", "joint_mean_cm", "add_auc_10cm", "pck_5px", "pck_10px", "frames")
    out += ["## More metrics (two-stage transfer | full training from scratch)", "",
            "| Family | " + " | ".join(extra_keys) + " | full: joint median cm | full: type acc % |",
            "|---|" + "---:|" * (len(extra_keys) + 2)]
    for f in fams:
        vals = [f"{ours[f][k]:.3f}" if k != "frames" else str(ours[f][k]) for k in extra_keys]
        fv = full.get(f, {})
        vals += [f"{fv.get('joint_median_cm', float('nan')):.2f}", f"{100 * fv.get('type_accuracy', float('nan')):.1f}"]
        out.append(f"| {f} | " + " | ".join(vals) + " |")
    out += depth_section(ours)
    for key in PASS_OPTIONS:
        out += option_section(key, single, test.get(key, {}), metrics.get("latency", {}))
    out += source_section(test.get("by_source", {}), test.get(headline, {}).get("by_source"),
                          PASS_OPTIONS[headline][1] if headline in PASS_OPTIONS else "")
    out += recording_section(metrics["transfer"]["test"].get("by_recording", {}))
    out += camera_pose_section(metrics["transfer"]["test"].get("camera_pose", {}))
    out += sequence_section(metrics["transfer"]["test"].get("sequence", {}))
    lat = metrics.get("latency", {})
    if "cpu" in lat:
        c = lat["cpu"]
        out += ["", f"Latency, batch 1: median **{c['batch1_median_ms']:.1f} ms** (p95 {c['batch1_p95_ms']:.1f} ms) "
                    f"on this machine's CPU with {c['threads']} threads ({c.get('processor', '')}); "
                    f"paper: {PAPER_LATENCY_MS[0]}-{PAPER_LATENCY_MS[1]} ms on a GTX 1080 Ti."]
        if "cuda" in lat:
            out.append(f"On {lat['cuda']['device']}: median {lat['cuda']['batch1_median_ms']:.1f} ms.")
    timing = metrics.get("timing", {})
    stages = [s for s in timing if isinstance(timing[s], dict) and "wall_s" in timing[s]]
    if stages:
        out += ["", "Training wall time: " + ", ".join(f"{s} {timing[s]['wall_s'] / 60:.1f} min "
                                                     f"({1000 * timing[s]['s_per_step']:.0f} ms/step)" for s in stages) + "."]
        speed = timing.get("stage1_step_speedup", {})
        if speed:
            out.append("A transfer stage-1 step (heads only, on cached trunk features) is "
                       + ", ".join(f"{v:.1f}x faster than a {k} step" for k, v in speed.items()) + ".")
    out += ["", "## Still short of the paper", ""]
    out += [f"- {s}" for s in short] or ["- nothing in the table above."]
    return "\n".join(out) + "\n"


def depth_section(ours: dict) -> list[str]:
    """Where the joint error comes from, per family: rays (2D) or depth (see armpose.metrics)."""
    keys = ("joint_median_cm", "joint_median_true_depth_cm", "depth_error_median_pct", "frame_depth_error_median_pct",
            "joint_median_true_frame_scale_cm")
    rows = [f for f in ours if all(k in ours[f] for k in keys[:4])]
    if not rows:
        return []
    out = ["", "## Where the joint error comes from (two-stage transfer)", "",
           "Joint median at true depth: each predicted joint slid along its own ray to the true depth, "
           "so what is left is the 2D (ray) error. Frame depth error: the depth error that all joints "
           "of a frame share, a scale error. Joint median at true frame scale: each frame's joints "
           "scaled about the camera centre by that shared error, so what is left is the 2D error and "
           "each joint's depth relative to the others.", "",
           "| Family | joint median cm | joint median at true depth cm | depth error median % | frame depth error median % "
           "| joint median at true frame scale cm |",
           "|---|---:|---:|---:|---:|---:|"]
    for f in rows:
        m = ours[f]
        scale = m.get(keys[4], float("nan"))
        out.append(f"| {f} | {m[keys[0]]:.2f} | {m[keys[1]]:.2f} | {m[keys[2]]:.1f} | {m[keys[3]]:.1f} | {scale:.2f} |")
    return out


PASS_OPTIONS = {   # key: (title, column tag, description, what the latency names)
    "mirror_test": ("Mirror test", "mirror",
                    "`armpose predict --mirror`: the image and its horizontal mirror in one batch, the mirrored "
                    "outputs mapped back and averaged (`armpose.mirror_test`).", "the mirror test"),
    "zoom_test": ("Zoom test", "zoom",
                  "`armpose predict --zoom`: a second look at the robot found by the first pass, from a camera "
                  "turned to it and moved closer until its box spans most of the frame, the view the network was "
                  "trained on in half its steps (`augment.zoom`); its outputs mapped back and averaged with the "
                  "first pass's (`armpose.zoom_test`).", "the zoom test"),
    "kinematic_fit": ("Kinematic fit", "fit",
                      "`armpose predict --zoom --fit`: the predicted type's own model (joint angles and pose, "
                      "forward kinematics of its description) fitted to the zoom test's estimate, on the rays and, "
                      "loosely, the depths of its points (`armpose.kinematic_fit`). No encoders, no calibration; "
                      "type and mask are the zoom test's.", "the zoom test and the fit"),
}


def pass_option(key: str, section: Mapping) -> tuple[str, str, str, str]:
    """``PASS_OPTIONS[key]``, told as run on the mirror test's passes when the metrics
    ``section`` of the zoom test or the fit says so (``on_mirror_test``, the evaluate stage's
    ``zoom_on_mirror``): ``armpose predict --mirror --zoom [--fit]``; the fit's caption also
    says which passes its weights were measured on (``sigmas_on_mirror_test``)."""
    title, short, what, phrase = PASS_OPTIONS[key]
    if key in ("zoom_test", "kinematic_fit") and section.get("on_mirror_test"):
        what = (what.replace("`armpose predict --", "`armpose predict --mirror --", 1)
                + " Every forward pass, the first and the second look, is the mirror test's: the image and its"
                  " horizontal mirror in one batch, the outputs averaged (`armpose.mirror_test.MirrorAveraged`).")
        phrase = phrase.replace("the zoom test", "the mirror and zoom tests", 1)
    if key == "kinematic_fit" and "sigmas_on_mirror_test" in section:
        passes = "mirror-averaged" if section["sigmas_on_mirror_test"] else "single"
        what += (" Its per-type weights were measured after stage 2 on held-out training frames, on "
                 f"{passes} passes (`transfer_stage2.fit_sigmas_on_mirror`, `armpose.fit_sigmas`).")
    return title, short, what, phrase


def option_section(key: str, ours: Mapping, other: Mapping, latency: Mapping) -> list[str]:
    """Markdown lines: the single pass (the table above) against a test-time option
    (``key`` of :data:`PASS_OPTIONS`: the mirror or the zoom test)."""
    fams = [f for f in ours if f in other.get("by_family", {})]
    if not fams:
        return []
    title, short, what, phrase = pass_option(key, other)
    cpu = latency.get("cpu", {})
    ms = f"{short}_batch1_median_ms"
    cost = (f" Latency at batch 1 on this CPU: {cpu['batch1_median_ms']:.1f} ms single, "
            f"{cpu[ms]:.1f} ms with {phrase}." if ms in cpu else "")
    out = ["", f"## {title} (two-stage transfer)", "", what + " Single: one forward pass of the network." + cost, "",
           f"| Family | joint median cm, single / {short} | base median cm, single / {short} | "
           f"type acc %, single / {short} | mask acc %, single / {short} |", "|---|---:|---:|---:|---:|"]
    for f in fams:
        a, b = ours[f], other["by_family"][f]
        out.append(f"| {f} | " + " | ".join(_pair(a, b, k, scale) for k, scale in (
            ("joint_median_cm", 1), ("base_median_cm", 1), ("type_accuracy", 100), ("mask_accuracy", 100))) + " |")
    return out


def source_section(by_source: Mapping, headline_by_source: Mapping | None = None, tag: str = "") -> list[str]:
    """Markdown lines: the synthetic test set and the recorded test recordings, per family, apart.
    With ``headline_by_source`` (the headline variant's ``by_source``, column tag ``tag``), each
    figure is shown as "single / headline"."""
    if "recorded" not in by_source:
        return []
    both = bool(headline_by_source) and all(s in headline_by_source for s in by_source)
    cols = ("mask acc %", "type acc %", "joint median cm", "base median cm")
    head = [f"{c}, single / {tag}" for c in cols] if both else list(cols)
    out = ["", "## Synthetic test set and recorded test recordings, apart (two-stage transfer)", "",
           "Recorded: whole held-out recordings of the record stage (simulated mocap-tracked handheld and "
           "tripod sessions; their labels carry calibration and mocap error).", "",
           "| Data | Family | frames | " + " | ".join(head) + " |", "|---|---|" + "---:|" * (len(cols) + 1)]
    for source, block in by_source.items():
        other = headline_by_source[source] if both else {}
        for f, m in {**block["by_family"], "all": block["all"]}.items():
            if m.get("frames"):
                h = (other.get("by_family", {}).get(f) if f != "all" else other.get("all")) if both else None
                out.append(f"| {source} | {f} | {m['frames']} | " + " | ".join(
                    _pair(m, h, k, scale) for k, scale in (("mask_accuracy", 100), ("type_accuracy", 100),
                                                           ("joint_median_cm", 1), ("base_median_cm", 1))) + " |")
    return out


def _pair(single: Mapping, other: Mapping | None, key: str, scale: float) -> str:
    """One cell: ``single[key]`` (times ``scale``), then `` / other[key]`` when ``other`` is given;
    one decimal for percentages, two for centimetres."""
    fmt = "{:.1f}" if scale == 100 else "{:.2f}"
    cell = fmt.format(scale * single[key])
    return cell if other is None else f"{cell} / {fmt.format(scale * other[key])}"


def recording_section(by_recording: Mapping) -> list[str]:
    """Markdown lines: each recorded test recording on its own (single pass), with the depth
    ratio its frames share (predicted over true; below 1: placed too close)."""
    if not by_recording:
        return []
    out = ["", "## Recorded test recordings, one by one (two-stage transfer, single pass)", "",
           "Depth ratio: per frame, the median over its joints of predicted over true depth; the median "
           "over the recording's frames (below 1: the robot placed too close).", "",
           "| Recording | robot | camera | frames | mask acc % | type acc % | joint median cm | "
           "joint median at true depth cm | base median cm | depth ratio |",
           "|---|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for name, m in by_recording.items():
        out.append(f"| {name} | {m['robot']} | {m['camera']} | {m['frames']} | {100 * m['mask_accuracy']:.1f} | "
                   f"{100 * m['type_accuracy']:.1f} | {m['joint_median_cm']:.2f} | "
                   f"{m['joint_median_true_depth_cm']:.2f} | {m['base_median_cm']:.2f} | "
                   f"{m['frame_depth_ratio_median']:.3f} |")
    return out


def _pose_cells(m: Mapping) -> str:
    count = m.get("frames", m.get("estimates", 0))
    if not count:
        return "| 0 | n/a | n/a | n/a | n/a |"
    return (f"| {count} | {m['rotation_median_deg']:.2f} | {m['translation_median_cm']:.2f} | "
            f"{m['add_median_cm']:.2f} | {m['add_auc_10cm']:.3f} |")


FIT_NAMES = {"rigid": "rigid", "rays": "rigid + rays"}


def _pose_rows(pose: Mapping) -> list[str]:
    """Table rows of one fit: synthetic single images, tripod single and pooled images."""
    fit = FIT_NAMES.get(pose.get("fit", "rigid"), pose.get("fit", "rigid"))
    out = [f"| {f} | synthetic | {fit} | 1 {_pose_cells(m)}" for f, m in pose.get("by_family", {}).items()]
    tripod = pose.get("tripod")
    if tripod:
        n = tripod["images_pooled"]
        for f, block in {**tripod["by_family"], "all": tripod["all"]}.items():
            out.append(f"| {f} | tripod | {fit} | 1 {_pose_cells(block['images_1'])}")
            out.append(f"| {f} | tripod | {fit} | {n} {_pose_cells(block[f'images_{n}'])}")
    return out


def camera_pose_section(pose: Mapping) -> list[str]:
    """Markdown lines: camera-to-robot pose per family, one image (synthetic, tripod) and pooled
    (tripod); with ``evaluate.pose_fit: rays``, the rigid fit alone below for comparison."""
    if not pose.get("by_family") and not pose.get("tripod"):
        return []
    out = ["", "## Camera-to-robot pose without calibration (beyond the paper)", "",
           "The predicted base and joints aligned with forward kinematics of the joint encoders: the Eye-to-Hand "
           "transform without a calibration. Fit *rigid*: a robust (Huber) rigid fit of the 3D points. "
           "*rigid + rays*: that fit refined so that each forward-kinematics point lies on the ray of its "
           f"predicted point (to {RAY_SIGMA:g} rad) and near its predicted depth (to {100 * LOG_DEPTH_SIGMA:g} %), "
           "the network's median errors on held-out training frames (`armpose.camera_pose.refine_rays`, "
           "`evaluate.pose_fit`). Synthetic: every "
           "test frame has its own camera, so one image per estimate. Tripod: the static-camera test recordings, "
           "one image per estimate, and one estimate pooled over N frames spread over the recording.", "",
           "| Family | data | fit | images | estimates | rotation median deg | translation median cm | ADD median cm "
           "| ADD AUC 10 cm |", "|---|---|---|---:|---:|---:|---:|---:|---:|"]
    out += _pose_rows(pose)
    if "rigid" in pose:
        out += _pose_rows(pose["rigid"])
    return out


def sequence_section(seq: Mapping) -> list[str]:
    """Markdown lines: unfiltered against filtered joints on the recorded test recordings, and the
    jitter reduction in words."""
    if not seq.get("all", {}).get("recordings"):
        return []
    filters = seq["filters"]
    out = ["", f"## Recorded test recordings as sequences ({seq['fps']:g} fps): unfiltered and filtered", "",
           "Causal filters of `armpose predict --sequence` (default tuning). Jitter: mean magnitude of the "
           "second difference over time, mm per frame^2. The labels' own jitter is what true motion leaves: small for "
           "a static camera; on moving-camera recordings it includes the per-frame mocap noise of the labels.", "",
           "| Recordings | count | frames | labels jitter | " + " | ".join(
               f"{v} joint median cm | {v} jitter" for v in ("unfiltered", *filters)) + " |",
           "|---|---:|---:|---:|" + "---:|---:|" * (len(filters) + 1)]
    blocks = {"all": seq["all"], **seq.get("by_family", {}), **{f"{k} camera": v for k, v in seq.get("by_camera", {}).items()}}
    for name, b in blocks.items():
        cells = [f"{b[v]['joint_median_cm']:.2f} | {b[v]['jitter_mm']:.2f}" for v in ("unfiltered", *filters)]
        out.append(f"| {name} | {b['recordings']} | {b['frames']} | {b['labels']['jitter_mm']:.2f} | " + " | ".join(cells) + " |")
    a = seq["all"]
    out += ["", "Jitter reduction on all recorded test recordings: " + "; ".join(
        f"{f} {a[f]['jitter_reduction']:.1f}x ({a[f]['jitter_reduction_pct']:.0f} % less jitter), joint median "
        f"{a['unfiltered']['joint_median_cm']:.2f} -> {a[f]['joint_median_cm']:.2f} cm" for f in filters) + "."]
    return out


def git_hash(root: Path) -> str:
    """The commit checked out at ``root``, with ``-dirty`` appended when tracked files other than
    the pipeline's own outputs (``dvc.lock``, ``results/``) differ from it: code or params that
    no commit holds. ``unknown`` outside a git checkout."""
    def git(*args: str) -> str:
        return subprocess.run(["git", *args], cwd=root, capture_output=True, text=True, check=True).stdout.strip()
    try:
        head = git("rev-parse", "HEAD")
        changed = git("status", "--porcelain", "--untracked-files=no", "--", ".", ":!dvc.lock", ":!results")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + ("-dirty" if changed else "")


VECTOR_ISAS = ("avx512_fp16", "avx512_bf16", "avx512f", "avx2", "avx", "sse4_2")


def cpu_description(cpuinfo: Path = Path("/proc/cpuinfo")) -> dict:
    """``{"model", "family_model", "vector_isa"}`` of this machine's CPU from ``cpuinfo`` (Linux):
    the model name, its "cpu family/model" numbers (virtual machines often show a generic name)
    and the widest of :data:`VECTOR_ISAS` it has. Floating-point results (renders, training) can
    differ in their last bits between CPUs with different vector units, so two runs of one commit
    are comparable bit for bit only on the same kind of CPU. ``None`` values where unreadable."""
    try:
        text = cpuinfo.read_text()
    except OSError:
        return {"model": None, "family_model": None, "vector_isa": None}
    fields = dict(line.split(":", 1) for line in text.splitlines()[:64] if ":" in line)
    fields = {k.strip(): v.strip() for k, v in fields.items()}
    flags = set(fields.get("flags", "").split())
    numbers = (fields.get("cpu family"), fields.get("model"))
    return {"model": fields.get("model name"), "family_model": "/".join(numbers) if all(numbers) else None,
            "vector_isa": next((f for f in VECTOR_ISAS if f in flags), None)}


def environment(root: Path, profile_note: str) -> dict:
    """The git hash, the machine, the package versions and the profile of this run."""
    versions = {}
    for pkg in PACKAGES:
        try:
            versions[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            versions[pkg] = None
    return {"git": git_hash(root), "profile": profile_note, "python": platform.python_version(),
            "machine": {"processor": platform.processor() or platform.machine(), "cpu_count": os.cpu_count(),
                        "platform": platform.platform(), "cpu": cpu_description()},
            "packages": versions}


def dumps(obj) -> str:
    return json.dumps(obj, indent=2, sort_keys=False)


README_START, README_END = "<!-- results:start -->", "<!-- results:end -->"


def update_readme(root: Path) -> bool:
    """Copy ``results/results_table.md`` (minus its title) between the README's result markers.
    Returns True if the README changed. ``python -m armpose.report`` runs it."""
    readme, table = Path(root) / "README.md", Path(root) / "results" / "results_table.md"
    text, body = readme.read_text(), table.read_text().split("\n", 1)[1].strip()
    body = "\n".join("#" + line if line.startswith("## ") else line for line in body.splitlines())  # under ## Results
    if README_START not in text or README_END not in text:
        raise ValueError(f"{readme}: no {README_START} ... {README_END} markers")
    head, rest = text.split(README_START, 1)
    new = f"{head}{README_START}\n{body}\n{README_END}{rest.split(README_END, 1)[1]}"
    if new != text:
        from armpose.io import atomic_write_text
        atomic_write_text(readme, new)
    return new != text


if __name__ == "__main__":
    from armpose.config import project_root
    print("README updated" if update_readme(project_root()) else "README already up to date")
