"""Run independent jobs on a process pool with a tqdm progress bar (frames per second)."""
from __future__ import annotations

import logging
import multiprocessing as mp
from typing import Callable, Iterable, Sequence

from tqdm import tqdm

log = logging.getLogger(__name__)


def _init_worker() -> None:
    import torch
    torch.set_num_threads(1)


def run_jobs(fn: Callable, jobs: Sequence, workers: int, weight: Callable = lambda job: 1,
             desc: str = "", unit: str = "frame") -> list:
    """``[fn(job) for job in jobs]`` on ``workers`` processes (in-process when 1), in job order.

    The bar advances by ``weight(job)`` per finished job, so its rate reads in ``unit``/s.
    """
    total = sum(weight(j) for j in jobs)
    results: list = [None] * len(jobs)
    with tqdm(total=total, desc=desc, unit=unit, dynamic_ncols=True) as bar:
        if workers <= 1 or len(jobs) <= 1:
            for i, job in enumerate(jobs):
                results[i] = fn(job)
                bar.update(weight(job))
            return results
        # fork starts workers in milliseconds with every module already imported (torch
        # re-initialises its CPU thread pool after fork, as DataLoader workers rely on);
        # spawn where fork does not exist
        ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
        with ctx.Pool(min(workers, len(jobs)), initializer=_init_worker) as pool:
            for i, res in pool.imap_unordered(_indexed(fn), list(enumerate(jobs))):
                results[i] = res
                bar.update(weight(jobs[i]))
    return results


class _indexed:
    """Picklable wrapper: ``(i, job) -> (i, fn(job))``."""

    def __init__(self, fn: Callable):
        self.fn = fn

    def __call__(self, item):
        i, job = item
        return i, self.fn(job)


def chunks(total: int, size: int) -> Iterable[tuple[int, int]]:
    """``(index, count)`` pairs splitting ``total`` items into chunks of at most ``size``."""
    for k, start in enumerate(range(0, total, size)):
        yield k, min(size, total - start)
