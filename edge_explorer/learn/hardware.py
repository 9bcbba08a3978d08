"""Where a stretch of training ran, in words, for the model cards' provenance (predictor and goal policy)."""

from __future__ import annotations

import os
import platform

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
