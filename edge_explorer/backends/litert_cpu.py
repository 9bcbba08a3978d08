"""LiteRT (ai-edge-litert, the TensorFlow Lite runtime) on the CPU with the XNNPACK delegate.

Int8 models keep quantized inputs and outputs so the Edge TPU and XNNPACK can run them end to end; this backend
quantizes the caller's float32 inputs with each input tensor's scale and zero point and dequantizes the outputs,
so callers never see integers.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
from ai_edge_litert.interpreter import Interpreter

from edge_explorer.backends.base import InferenceBackend, TensorSpec


def _spec(detail: dict) -> TensorSpec:
    """TensorSpec of an interpreter tensor detail; per-tensor quantization only (what I/O tensors use)."""
    shape = tuple(int(d) for d in detail.get("shape_signature", detail["shape"]))
    dtype = np.dtype(detail["dtype"]).name
    params = detail.get("quantization_parameters", {})
    scales, zero_points = params.get("scales", ()), params.get("zero_points", ())
    if len(scales) > 1:
        raise ValueError(f"tensor {detail['name']!r} is quantized per axis; model inputs/outputs must be per tensor")
    if len(scales) == 1 and scales[0] > 0:
        return TensorSpec(detail["name"], shape, dtype, float(scales[0]), int(zero_points[0]))
    return TensorSpec(detail["name"], shape, dtype)


def quantize(values: np.ndarray, spec: TensorSpec) -> np.ndarray:
    """Float values → the tensor's integer type: round(v / scale) + zero_point, saturated."""
    info = np.iinfo(spec.dtype)
    q = np.round(np.asarray(values, dtype=np.float32) / np.float32(spec.scale)) + spec.zero_point
    return np.clip(q, info.min, info.max).astype(spec.dtype)


def dequantize(values: np.ndarray, spec: TensorSpec) -> np.ndarray:
    """Integer tensor values → float32: scale · (q − zero_point)."""
    return ((values.astype(np.float32) - np.float32(spec.zero_point)) * np.float32(spec.scale)).astype(np.float32)


class LiteRtCpuBackend(InferenceBackend):
    """``litert-cpu``: the LiteRT interpreter; its default op resolver applies XNNPACK on the CPU."""

    name = "litert-cpu"
    artifact_format = "tflite"

    def load(self, path: Path) -> None:
        self._interpreter = self._make_interpreter(path)
        self._interpreter.allocate_tensors()
        self._input_details = self._interpreter.get_input_details()
        self._output_details = self._interpreter.get_output_details()
        self.inputs = tuple(_spec(d) for d in self._input_details)
        self.outputs = tuple(_spec(d) for d in self._output_details)

    def _make_interpreter(self, path: Path) -> Interpreter:
        return Interpreter(model_path=str(path), num_threads=self.num_threads)

    def run(self, inputs: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        self._check_inputs(inputs)
        for spec, detail in zip(self.inputs, self._input_details, strict=True):
            value = inputs[spec.name]
            tensor = quantize(value, spec) if spec.quantized else np.asarray(value, dtype=spec.dtype)
            self._interpreter.set_tensor(detail["index"], tensor)
        self._interpreter.invoke()
        out = {}
        for spec, detail in zip(self.outputs, self._output_details, strict=True):
            value = self._interpreter.get_tensor(detail["index"])
            out[spec.name] = dequantize(value, spec) if spec.quantized else value.astype(np.float32)
        return out
