"""The interface every inference backend implements, and the description of a model's tensors."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from edge_explorer.errors import EdgeExplorerError


class BackendUnavailable(EdgeExplorerError):
    """This backend cannot run on this host (missing library or accelerator, wrong artifact kind)."""


@dataclass(frozen=True)
class TensorSpec:
    """A model input or output as stored in the artifact.

    ``shape`` uses −1 for a dynamic dimension; ``dtype`` is the numpy name of the stored type (``"int8"`` for a
    quantized tensor even though callers exchange float32). Quantized tensors carry ``scale`` and ``zero_point``:
    ``real = scale · (q − zero_point)``.
    """

    name: str
    shape: tuple[int, ...]
    dtype: str
    scale: float | None = None
    zero_point: int | None = None

    @property
    def quantized(self) -> bool:
        return self.scale is not None

    def accepts_shape(self, shape: tuple[int, ...]) -> bool:
        """Whether an array of ``shape`` fits (−1 dimensions match anything)."""
        return len(shape) == len(self.shape) and all(d == -1 or d == s for d, s in zip(self.shape, shape, strict=True))


class InferenceBackend(ABC):
    """Loads one model artifact and runs it. ``run`` takes and returns float32 arrays keyed by tensor name."""

    name: ClassVar[str]  # as written in device profiles' backend order
    artifact_format: ClassVar[str]  # the model-card format it runs: "onnx", "tflite" or "edgetpu_tflite"

    def __init__(self, num_threads: int = 1) -> None:
        if num_threads < 1:
            raise ValueError(f"num_threads must be ≥ 1, got {num_threads}")
        self.num_threads = num_threads
        self.inputs: tuple[TensorSpec, ...] = ()
        self.outputs: tuple[TensorSpec, ...] = ()

    @abstractmethod
    def load(self, path: Path) -> None:
        """Load the artifact; raises :class:`BackendUnavailable` when this host cannot run this backend."""

    @abstractmethod
    def run(self, inputs: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """One inference: float32 arrays in, by input name; float32 arrays out, by output name."""

    def _check_inputs(self, inputs: Mapping[str, np.ndarray]) -> None:
        """Raise ValueError naming any missing, unexpected or wrongly shaped input."""
        if not self.inputs:
            raise RuntimeError(f"{self.name}: call load() before run()")
        expected = {spec.name for spec in self.inputs}
        if set(inputs) != expected:
            raise ValueError(f"{self.name}: inputs {sorted(inputs)} given, the model takes {sorted(expected)}")
        for spec in self.inputs:
            shape = tuple(np.shape(inputs[spec.name]))
            if not spec.accepts_shape(shape):
                raise ValueError(f"{self.name}: input {spec.name!r} has shape {shape}, the model takes {spec.shape}")
