"""Where a stretch of training ran, in words, for the model cards' provenance (predictor and goal policy)."""

from __future__ import annotations

import os
import platform

import torch


def hardware_description(device: str, loader_workers: int, threads: int) -> str:
    """Where a stretch of training ran, in words, for the model card's provenance."""
    cpu = f"{platform.machine()}, {os.cpu_count()} cores"
    loaders = f", {loader_workers} loader workers" if loader_workers else ""
    if device == "cuda":
        return f"{torch.cuda.get_device_name()} (bfloat16 autocast), {cpu}{loaders}"
    return f"{cpu}, CPU only, {threads} torch thread(s){loaders}"
