"""onnxruntime on the CPU: float32 and QDQ-int8 ONNX models (the quantization lives inside the graph).

onnxruntime is imported when a model is loaded, not with this module: the daemon imports every backend of the
chain, and a run whose models all load on LiteRT or the Edge TPU should not carry its ~17 MB.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from edge_explorer.backends.base import InferenceBackend, TensorSpec

if TYPE_CHECKING:
    import onnxruntime as ort

# onnxruntime's type strings → numpy dtype names.
_ORT_DTYPES = {
    "tensor(float)": "float32",
    "tensor(float16)": "float16",
    "tensor(double)": "float64",
    "tensor(int8)": "int8",
    "tensor(uint8)": "uint8",
    "tensor(int32)": "int32",
    "tensor(int64)": "int64",
    "tensor(bool)": "bool",
}


def _spec(arg: ort.NodeArg) -> TensorSpec:
    shape = tuple(d if isinstance(d, int) else -1 for d in arg.shape)
    return TensorSpec(arg.name, shape, _ORT_DTYPES.get(arg.type, arg.type))


class OnnxRuntimeCpuBackend(InferenceBackend):
    """``onnxruntime-cpu``: one ``InferenceSession`` with the CPU execution provider and all graph optimisations."""

    name = "onnxruntime-cpu"
    artifact_format = "onnx"

    def load(self, path: Path) -> None:
        import onnxruntime as ort

        options = ort.SessionOptions()
        options.intra_op_num_threads = self.num_threads
        options.inter_op_num_threads = 1
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        self._session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        self.inputs = tuple(_spec(a) for a in self._session.get_inputs())
        self.outputs = tuple(_spec(a) for a in self._session.get_outputs())

    def run(self, inputs: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        self._check_inputs(inputs)
        feed = {spec.name: np.asarray(inputs[spec.name], dtype=spec.dtype) for spec in self.inputs}
        names = [spec.name for spec in self.outputs]
        values = self._session.run(names, feed)
        return {name: np.asarray(value, dtype=np.float32) for name, value in zip(names, values, strict=True)}
