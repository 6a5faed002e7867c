"""Wall time of the whole pipeline, stage by stage: runs ``dvc repro`` and timestamps its stages.

    python benchmarks/time_pipeline.py [--force]

Run it in a fresh clone (no DVC cache, no data) to time what a user's first ``dvc repro``
costs; ``--force`` passes ``-f`` to re-run stages that are up to date (persistent outputs such as
rendered recordings are kept by the stages themselves, so remove ``data/`` and ``models/``
first for a cold run). Writes ``results/pipeline_time.json``: seconds per stage, the total,
the machine and the profile. The issue's budget for the default profile: 60 min on the
2-core reference machine.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import re
import subprocess
import sys
import time
from pathlib import Path

from armpose.config import project_root
from armpose.io import atomic_write_json

STAGE_LINE = re.compile(r"^Running stage '([^']+)'")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--force", action="store_true", help="dvc repro -f")
    ap.add_argument("--profile", default="default", help="the profile params.yaml holds (recorded only)")
    args = ap.parse_args()
    root = project_root()
    cmd = ["dvc", "repro"] + (["-f"] if args.force else [])
    starts: list[tuple[str, float]] = []
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=root, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1)
    for line in proc.stdout:
        sys.stdout.write(line)
        m = STAGE_LINE.match(line.strip())
        if m:
            starts.append((m.group(1), time.perf_counter()))
    rc = proc.wait()
    end = time.perf_counter()
    stages = {name: round((starts[i + 1][1] if i + 1 < len(starts) else end) - t, 1) for i, (name, t) in enumerate(starts)}
    out = {"command": " ".join(cmd), "returncode": rc, "profile": args.profile, "stages_s": stages,
           "total_s": round(end - t0, 1), "total_min": round((end - t0) / 60, 2), "budget_min": 60,
           "machine": {"cpu_count": os.cpu_count(), "processor": platform.processor() or platform.machine(),
                       "python": platform.python_version()}}
    atomic_write_json(root / "results" / "pipeline_time.json", out)
    print(json.dumps(out, indent=2))
    sys.exit(rc)


if __name__ == "__main__":
    main()
