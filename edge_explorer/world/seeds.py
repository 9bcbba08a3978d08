"""Seeds derived from a benchmark seed and a building's name, shared by the exploration benchmark
(:mod:`edge_explorer.bench.explore`), the simulator's start poses (:mod:`edge_explorer.sim.starts`) and the daemon's
flights (``edge-explorer run --seed --run-index``): a building's seeds do not depend on which other buildings are
flown."""

from __future__ import annotations

import zlib

import numpy as np


def derived_seed(seed: int, plan_name: str, *slot: int) -> int:
    sequence = np.random.SeedSequence(entropy=seed, spawn_key=(zlib.crc32(plan_name.encode()), *slot))
    return int(sequence.generate_state(1, dtype=np.uint32)[0])


def run_seed(seed: int, plan_name: str, run: int) -> int:
    """Noise seed of run ``run`` on a building: depends on the benchmark seed, the building's name and the run."""
    return derived_seed(seed, plan_name, run + 1)
