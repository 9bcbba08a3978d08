"""The host's figures for the model cards (predictor and goal policy): where a stretch of training ran, in words,
and how long one forward pass of a torch network takes here."""

from __future__ import annotations

import os
import platform
import statistics
import time
from collections.abc import Callable
from typing import Any

import torch


def hardware_description(device: str, loader_workers: int, threads: int, bfloat16: bool | None = None) -> str:
    """Where a stretch of training ran, in words, for the model card's provenance.

    ``bfloat16`` says whether the forward pass ran in bfloat16 autocast; ``None`` means the device's default
    (on CUDA, off on the CPU)."""
    bfloat16 = device == "cuda" if bfloat16 is None else bfloat16
    cpu = f"{platform.machine()}, {os.cpu_count()} cores"
    loaders = f", {loader_workers} loader workers" if loader_workers else ""
    if device == "cuda":
        precision = " (bfloat16 autocast)" if bfloat16 else ""
        return f"{torch.cuda.get_device_name()}{precision}, {cpu}{loaders}"
    precision = ", bfloat16 autocast" if bfloat16 else ""
    return f"{cpu}, CPU only, {threads} torch thread(s){precision}{loaders}"


def torch_latency_ms(run: Callable[[], object], repeats: int = 30, threads: int = 1) -> dict[str, Any]:
    """Median / p90 wall time of ``run()`` (one forward pass) with ``threads`` torch threads, after 5 warm-up calls;
    the load average says how busy the host was, since the figure is this host's at that moment."""
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    times = []
    try:
        with torch.no_grad():
            for k in range(repeats + 5):
                t0 = time.perf_counter()
                run()
                if k >= 5:
                    times.append(1e3 * (time.perf_counter() - t0))
    finally:
        torch.set_num_threads(previous)
    times.sort()
    return {
        "median_ms": statistics.median(times),
        "p90_ms": times[int(0.9 * (len(times) - 1))],
        "threads": threads,
        "repeats": repeats,
        "load_average_1min": os.getloadavg()[0],
    }
