"""ONNX artifacts: fp32 from torch (dynamo exporter, opset 18) and int8 QDQ from onnxruntime's static quantization.

* :func:`export_fp32`: ``torch.onnx.export(dynamo=True)`` (onnxscript), the graph checked by ``onnx.checker``
  (full check, with shape inference), and the exporter's metadata in ``metadata_props``. A ``Gather`` of one
  constant index (torch's ``x[:, 0]``, e.g. the goal policy's score channel) becomes ``Slice`` + ``Squeeze``
  (:func:`gather_to_slice`): the same values, and ops the Edge TPU has (it has no GATHER).
* :func:`quantize_int8`: ``onnxruntime.quantization.quantize_static`` in the QDQ format (int8 activations and
  weights, per-channel weights when the recipe says so) after ``quant_pre_process`` (shape inference + graph
  optimisation), calibrated on the recipe's observations with the recipe's method (MinMax / Entropy /
  Percentile). Inputs and outputs stay float32: the quantization lives inside the graph. With the recipe's
  ``onnx_float_output_conv`` the graph's last Conv (:func:`last_conv`) stays float (onnxruntime's
  ``nodes_to_exclude``): the int8 ONNX serves CPUs, where that tiny layer costs nothing; the full-integer TFLite
  is the Edge TPU's artifact.
* :func:`qdq_error_report`: when a gate fails, onnxruntime's ``qdq_loss_debug`` runs the fp32 and the QDQ model on
  the held-back observations and gives every activation tensor's signal-to-quantization-noise ratio (dB), worst
  first — the tensors to look at (or exclude from quantization).
"""

from __future__ import annotations

import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
import onnx
import torch
from onnx import numpy_helper
from onnxruntime.quantization import CalibrationDataReader, CalibrationMethod, QuantFormat, QuantType, quantize_static
from onnxruntime.quantization.shape_inference import quant_pre_process

from edge_explorer.export.calibration import Feed
from edge_explorer.export.networks import ExportNetwork
from edge_explorer.export.recipe import QuantizationConfig

OPSET = 18
METHODS = {
    "minmax": CalibrationMethod.MinMax,
    "entropy": CalibrationMethod.Entropy,
    "percentile": CalibrationMethod.Percentile,
}


def export_fp32(network: ExportNetwork, path: Path) -> None:
    """Write the fp32 ONNX model of ``network`` to ``path`` (checked, with metadata)."""
    with torch.no_grad():
        program = torch.onnx.export(
            network.module,
            network.example(),
            dynamo=True,
            opset_version=OPSET,
            input_names=list(network.inputs),
            output_names=list(network.outputs),
            verbose=False,
        )
    program.save(str(path))
    model = onnx.load(str(path))
    model.producer_name = "edge-explorer export"
    # The exporter's own props (torch node names, graph signature) are debugging noise in a shipped model.
    del model.metadata_props[:]
    gather_to_slice(model)
    onnx.helper.set_model_props(model, network.metadata)
    onnx.save(model, str(path))
    onnx.checker.check_model(str(path), full_check=True)


def gather_to_slice(model: onnx.ModelProto) -> int:
    """Rewrite every ``Gather(x, i)`` with a constant scalar index ``i`` as ``Squeeze(Slice(x, i, i + 1, axis),
    axis)``: exact. Returns the number of rewrites; the model is changed in place."""
    graph = model.graph
    constants = {t.name: numpy_helper.to_array(t) for t in graph.initializer}
    constant_nodes = (n for n in graph.node if n.op_type == "Constant" and n.attribute[0].name == "value")
    constants.update({n.output[0]: numpy_helper.to_array(n.attribute[0].t) for n in constant_nodes})
    rewrites = 0
    for gather in [n for n in graph.node if n.op_type == "Gather"]:
        index = constants.get(gather.input[1])
        if index is None or index.ndim != 0:
            continue
        axis = next((a.i for a in gather.attribute if a.name == "axis"), 0)
        start = int(index)
        end = start + 1 if start != -1 else np.iinfo(np.int64).max
        names = [f"{gather.name or gather.output[0]}_{k}" for k in ("starts", "ends", "axes", "sliced")]
        for name, value in zip(names[:3], (start, end, axis), strict=True):
            graph.initializer.append(numpy_helper.from_array(np.array([value], np.int64), name))
        at = list(graph.node).index(gather)
        graph.node.remove(gather)
        graph.node.insert(at, onnx.helper.make_node("Slice", [gather.input[0], *names[:3]], [names[3]]))
        graph.node.insert(at + 1, onnx.helper.make_node("Squeeze", [names[3], names[2]], [gather.output[0]]))
        rewrites += 1
        if not any(gather.input[1] in node.input for node in graph.node):  # drop the index nothing reads any more
            for unused in [t for t in graph.initializer if t.name == gather.input[1]]:
                graph.initializer.remove(unused)
            for unused in [n for n in graph.node if n.op_type == "Constant" and gather.input[1] in n.output]:
                graph.node.remove(unused)
    return rewrites


class FeedReader(CalibrationDataReader):
    """onnxruntime's calibration reader over a list of feeds (one observation each)."""

    def __init__(self, feeds: Sequence[Feed]) -> None:
        self._feeds = list(feeds)
        self._iter: Iterator[Feed] = iter(self._feeds)

    def get_next(self) -> Feed | None:
        return next(self._iter, None)

    def rewind(self) -> None:
        self._iter = iter(self._feeds)


def last_conv(path: Path) -> str:
    """The name of the graph's last Conv node (in graph order): for the goal policy the windowed scores' 2 → 1
    combination, whose int8 output step decides near-ties (``docs/policy/export_int8.md``)."""
    convs = [node.name for node in onnx.load(str(path)).graph.node if node.op_type == "Conv"]
    if not convs:
        raise ValueError(f"{path}: no Conv node to leave in float (recipe onnx_float_output_conv)")
    return convs[-1]


def quantize_int8(fp32_path: Path, out_path: Path, feeds: Sequence[Feed], config: QuantizationConfig) -> None:
    """Static int8 QDQ quantization of ``fp32_path`` calibrated on ``feeds``; written to ``out_path``."""
    with tempfile.TemporaryDirectory() as tmp:
        prepared = Path(tmp) / "prepared.onnx"
        quant_pre_process(str(fp32_path), str(prepared), skip_symbolic_shape=True)
        quantize_static(
            str(prepared),
            str(out_path),
            FeedReader(feeds),
            quant_format=QuantFormat.QDQ,
            activation_type=QuantType.QInt8,
            weight_type=QuantType.QInt8,
            per_channel=config.per_channel,
            calibrate_method=METHODS[config.method],
            nodes_to_exclude=[last_conv(prepared)] if config.onnx_float_output_conv else [],
            extra_options={"CalibPercentile": config.percentile, "CalibTensorRangeSymmetric": False},
        )
    model = onnx.load(str(out_path))
    onnx.helper.set_model_props(model, {p.key: p.value for p in onnx.load(str(fp32_path)).metadata_props})
    onnx.save(model, str(out_path))
    onnx.checker.check_model(str(out_path))


def qdq_error_report(fp32_path: Path, int8_path: Path, feeds: Sequence[Feed], worst: int = 10) -> list[dict]:
    """Per activation tensor: SQNR (dB) of the QDQ model's value against fp32's (``xmodel_err``) and of the tensor
    against its own quantize–dequantize (``qdq_err``), sorted worst first, at most ``worst`` rows."""
    from onnxruntime.quantization.qdq_loss_debug import (
        collect_activations,
        compute_activation_error,
        create_activation_matching,
        modify_model_output_intermediate_tensors,
    )

    with tempfile.TemporaryDirectory() as tmp:
        aug_fp32, aug_int8 = Path(tmp) / "fp32.onnx", Path(tmp) / "int8.onnx"
        modify_model_output_intermediate_tensors(str(fp32_path), str(aug_fp32))
        modify_model_output_intermediate_tensors(str(int8_path), str(aug_int8))
        fp32_acts = collect_activations(str(aug_fp32), FeedReader(feeds))
        int8_acts = collect_activations(str(aug_int8), FeedReader(feeds))
    errors = compute_activation_error(create_activation_matching(int8_acts, fp32_acts))
    rows = [
        {"tensor": name, "xmodel_sqnr_db": float(e.get("xmodel_err", np.nan)), "qdq_sqnr_db": float(e["qdq_err"])}
        for name, e in errors.items()
    ]
    rows.sort(key=lambda r: r["xmodel_sqnr_db"] if np.isfinite(r["xmodel_sqnr_db"]) else np.inf)
    return rows[:worst]
