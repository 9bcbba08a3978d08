"""Test-time averaging of the predictor (issue #17, session 32): predictor callables for ``f1_bound.py --model``.

The U-Net is trained with flips and 90° rotations, so every element of the dihedral group D4 maps a window to
another window it was trained on. Averaging the probabilities over some of those transforms (each one undone on
the output) is the cheapest ensemble there is: one model, k passes. ``ensemble`` averages two different trainings
instead (the shipped stretch 6 and the session-31 host decay run).

    python docs/predictor/session19/f1_bound.py collect ... --model docs.predictor.session32.tta:flip2
"""

from __future__ import annotations

import os

import numpy as np
import torch

from edge_explorer.learn.unet import load_unet
from edge_explorer.predict.encoding import encode_windows

SHIPPED = os.environ.get("TTA_WEIGHTS", "models/predictor/predictor.safetensors")
SECOND = os.environ.get("TTA_SECOND", "runs/predictor_host_decay/best.safetensors")
torch.set_num_threads(int(os.environ.get("TTA_THREADS", "2")))


def _transforms(k: int) -> list[tuple[int, bool]]:
    """The first k elements of D4 as (quarter turns, mirror), identity first, the mirror second."""
    order = [(0, False), (0, True), (2, False), (2, True), (1, False), (1, True), (3, False), (3, True)]
    return order[:k]


class Averaged:
    """Mean probability of ``models`` over the first ``k`` dihedral transforms of the window."""

    def __init__(self, weights: list[str], k: int) -> None:
        self.models = [load_unet(w, "cpu").eval() for w in weights]
        self.k = k

    @torch.no_grad()
    def __call__(self, window: np.ndarray) -> np.ndarray:
        views = []
        for turns, mirror in _transforms(self.k):
            w = np.rot90(window, turns)
            views.append(np.fliplr(w) if mirror else w)
        x = torch.from_numpy(encode_windows(np.ascontiguousarray(np.stack(views))))
        out = np.zeros(window.shape, np.float64)
        for model in self.models:
            probs = model(x).numpy()[:, 0]
            for p, (turns, mirror) in zip(probs, _transforms(self.k), strict=True):
                p = np.fliplr(p) if mirror else p
                out += np.rot90(p, -turns)
        return (out / (self.k * len(self.models))).astype(np.float32)


_cache: dict[str, Averaged] = {}


def _get(name: str, weights: list[str], k: int) -> Averaged:
    if name not in _cache:
        _cache[name] = Averaged(weights, k)
    return _cache[name]


def identity(window: np.ndarray) -> np.ndarray:
    return _get("identity", [SHIPPED], 1)(window)


def flip2(window: np.ndarray) -> np.ndarray:
    return _get("flip2", [SHIPPED], 2)(window)


def d4_4(window: np.ndarray) -> np.ndarray:
    return _get("d4_4", [SHIPPED], 4)(window)


def d4_8(window: np.ndarray) -> np.ndarray:
    return _get("d4_8", [SHIPPED], 8)(window)


def ensemble(window: np.ndarray) -> np.ndarray:
    return _get("ensemble", [SHIPPED, SECOND], 1)(window)
