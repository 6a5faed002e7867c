"""Forward latency per frame at batch 1 (median, p95 over >= 200 frames) and batch-32 throughput.

    python benchmarks/bench_inference.py [--params params.yaml]

The same function as the pipeline's ``latency`` stage (:mod:`armpose.stages.latency`): CPU
with the ``latency.threads`` torch threads, and CUDA when present. Writes
``results/latency.json``. Target on the 2-core reference machine: median <= 15 ms at batch 1.
"""
from armpose.stages.latency import main

if __name__ == "__main__":
    main()
