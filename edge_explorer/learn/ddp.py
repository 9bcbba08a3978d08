"""Data-parallel predictor training under ``torchrun``: torch's DistributedDataParallel, gloo on CPU, NCCL on GPU.

``torchrun --nproc_per_node N … edge-explorer train predictor`` starts N processes with ``WORLD_SIZE``, ``RANK``
and ``LOCAL_RANK`` in their environment; :func:`init_from_env` joins them into one process group (and without
``WORLD_SIZE`` > 1 returns the single-process :class:`Ranks`, touching nothing). The config's ``batch_size`` stays
the *global* batch: every rank takes its contiguous share (:meth:`Ranks.shard`) of the same per-epoch permutation,
and :func:`global_weighted_mean` divides the summed weighted loss by the whole batch's weight, so the gradient DDP
averages is the single-process gradient of the same batch and the learning-rate schedule, counted in steps, is
unchanged. One difference remains: BatchNorm normalises over each rank's share (standard DDP; torch's
SyncBatchNorm runs on GPUs only), so losses agree closely, not bit for bit.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch
import torch.distributed as dist
from torch import nn
from torch.nn.parallel import DistributedDataParallel

from edge_explorer.errors import EdgeExplorerError


@dataclass(frozen=True)
class Ranks:
    """This process's place in the job: rank 0 of 1 without torchrun."""

    rank: int = 0
    world_size: int = 1

    @property
    def distributed(self) -> bool:
        return self.world_size > 1

    @property
    def is_main(self) -> bool:
        """The one process that writes checkpoints, logs and the best model."""
        return self.rank == 0

    def shard(self, indices: list[int]) -> list[int]:
        """This rank's contiguous share of a global batch (whose size the world size divides)."""
        per_rank = len(indices) // self.world_size
        return indices[self.rank * per_rank : (self.rank + 1) * per_rank]


def init_from_env(device: str, global_batch: int) -> Ranks:
    """Join torchrun's process group when ``WORLD_SIZE`` > 1 (NCCL for ``cuda``, gloo for ``cpu``)."""
    world_size = int(os.environ.get("WORLD_SIZE", "1"))
    if world_size <= 1:
        return Ranks()
    if global_batch % world_size:
        raise EdgeExplorerError(f"batch_size {global_batch} is not a multiple of the {world_size} torchrun processes")
    if device == "cuda":
        torch.cuda.set_device(int(os.environ.get("LOCAL_RANK", "0")))
    if not dist.is_initialized():
        dist.init_process_group("nccl" if device == "cuda" else "gloo")
    return Ranks(dist.get_rank(), world_size)


class _Logits(nn.Module):
    """The U-Net's logits as ``forward``: DDP synchronises gradients of what goes through its own ``forward``."""

    def __init__(self, unet: nn.Module) -> None:
        super().__init__()
        self.unet = unet

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.unet.logits(x)


def data_parallel_logits(unet: nn.Module, device: str) -> nn.Module:
    """A DDP module computing ``unet.logits``; it shares ``unet``'s parameters, so checkpoints save ``unet``."""
    device_ids = [torch.cuda.current_device()] if device == "cuda" else None
    return DistributedDataParallel(_Logits(unet), device_ids=device_ids)


def global_weighted_mean(numerator: torch.Tensor, weight_sum: torch.Tensor, ranks: Ranks) -> tuple[torch.Tensor, float]:
    """(the loss to backpropagate, the global batch's loss) of this rank's Σ w·loss and Σ w.

    The backpropagated loss is ``world_size · numerator / Σ_all w``: DDP averages gradients over the ranks, which
    leaves ∇(Σ_all w·loss) / Σ_all w, the gradient of the whole batch's weighted mean.
    """
    totals = torch.stack([numerator.detach(), weight_sum.detach()])
    dist.all_reduce(totals)
    total_weight = totals[1].clamp_min(1e-6)
    return numerator * ranks.world_size / total_weight, float(totals[0] / total_weight)


def finish(ranks: Ranks) -> None:
    """Wait for every rank (rank 0 may still be validating) and leave the process group."""
    if ranks.distributed:
        dist.barrier()
        dist.destroy_process_group()
