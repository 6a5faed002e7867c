"""Labelled frames per second of render + labels at 480x360, on this machine.

    python benchmarks/bench_data.py [--frames-per-robot 60] [--workers 2]

Runs the real stage functions on the default profile's settings (only the frame counts
shrunk) in a temporary folder, prints the rates and writes ``results/bench_data.json``.
Target on the 2-core reference machine: >= 25 labelled frames/s.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path

from armpose.config import profile_params, project_root
from armpose.io import atomic_write_json
from armpose.stages import labels, render


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames-per-robot", type=int, default=200)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default=str(project_root() / "results" / "bench_data.json"))
    args = ap.parse_args()
    params = profile_params("default")
    params["render"]["frames_per_robot"] = {r: args.frames_per_robot for r in params["base"]["robot_types"]}
    params["base"]["num_workers"] = args.workers
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        res = render.run(params, Path(tmp))
        t1 = time.perf_counter()
        labels.run(params, Path(tmp))
        t2 = time.perf_counter()
    n = res["frames"]
    cam = params["base"]["camera"]
    out = {
        "frames": n, "resolution": f"{cam['width']}x{cam['height']}", "workers": args.workers,
        "render_fps": round(n / (t1 - t0), 2), "labels_fps": round(n / (t2 - t1), 2),
        "render_plus_labels_fps": round(n / (t2 - t0), 2), "target_fps": 25.0,
        "machine": {"cpu_count": os.cpu_count(), "processor": platform.processor() or platform.machine(),
                    "python": platform.python_version()},
        "command": f"python benchmarks/bench_data.py --frames-per-robot {args.frames_per_robot} --workers {args.workers}",
    }
    atomic_write_json(Path(args.out), out)
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
