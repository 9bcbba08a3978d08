"""Every model on every backend, MACs from the graph, and the Edge TPU entry of the card."""

from __future__ import annotations

import json

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper, numpy_helper

from edge_explorer.backends.base import TensorSpec
from edge_explorer.backends.card import ArtifactCard, write_card
from edge_explorer.errors import EdgeExplorerError
from edge_explorer.profiling.models import bench_models, count_onnx, feed_for, graph_size, time_calls
from tests.predict.test_predictor import write_predictor_model

ALL = ("edgetpu", "litert-cpu", "onnxruntime-cpu")


def write_conv_model(folder, extra=None):
    """One 3×3 conv, 2 → 8 channels on 16×16, 'same' padding: 8·16·16·2·9 = 36 864 MACs, 152 parameters."""
    folder.mkdir(parents=True)
    weights = numpy_helper.from_array(np.ones((8, 2, 3, 3), np.float32), "W")
    bias = numpy_helper.from_array(np.zeros(8, np.float32), "B")
    graph = helper.make_graph(
        [helper.make_node("Conv", ["x", "W", "B"], ["y"], pads=[1, 1, 1, 1])],
        "conv",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 2, 16, 16])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 8, 16, 16])],
        [weights, bias],
    )
    path = folder / "conv_fp32.onnx"
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)], ir_version=8), path)
    specs = [TensorSpec("x", (1, 2, 16, 16), "float32")], [TensorSpec("y", (1, 8, 16, 16), "float32")]
    write_card(folder / "card.json", "conv", [ArtifactCard.describe(path, "onnx", *specs)], extra)
    return folder / "card.json"


def test_macs_and_parameters_are_counted_from_the_graph(tmp_path):
    pytest.importorskip("onnx_tool")
    card = write_conv_model(tmp_path / "conv")
    macs, params = count_onnx(card.parent / "conv_fp32.onnx")
    assert 36_864 <= macs <= 36_864 + 8 * 16 * 16  # onnx-tool may count the bias add as MACs too
    assert params == 152
    size = graph_size(card)
    assert size.macs == macs and "onnx-tool" in size.source


def test_the_cards_own_figures_win(tmp_path):
    card = write_conv_model(tmp_path / "conv", {"graph": {"macs": 123.0, "params": 4}})
    size = graph_size(card)
    assert (size.macs, size.params, size.source) == (123.0, 4.0, "model card")


def test_every_artifact_on_every_backend_missing_models_and_edgetpu_entries(tmp_path):
    card = write_predictor_model(tmp_path / "predictor", window=32, edgetpu=True)
    doc = json.loads(card.read_text())
    doc["export"] = {"formats": {"tflite_int8": {"edgetpu": {"ops_on_tpu": 12, "ops_on_cpu": 1}}}}
    card.write_text(json.dumps(doc))
    infos = {m.name: m for m in bench_models(tmp_path, ALL, repeats=5, warmup=1)}
    policy, predictor = infos["policy"], infos["predictor"]
    assert not policy.present and "card.json is missing" in policy.note and policy.runs == ()
    assert predictor.present and predictor.edgetpu == {"ops_on_tpu": 12, "ops_on_cpu": 1}
    runs = {(r.backend, r.precision): r for r in predictor.runs}
    assert set(runs) == {("edgetpu", "int8"), ("onnxruntime-cpu", "fp32"), ("litert-cpu", "–")}
    assert runs[("litert-cpu", "–")].note == "no tflite artifact in the card"
    onnx_run = runs[("onnxruntime-cpu", "fp32")]
    assert onnx_run.samples_ms.shape == (5,) and (onnx_run.samples_ms > 0).all()
    assert onnx_run.artifact == "predictor_fp32.onnx"
    tpu = runs[("edgetpu", "int8")]
    assert tpu.samples_ms is None and "edgetpu" in tpu.note  # no Edge TPU here: said why, not measured
    only_onnx = bench_models(tmp_path, ("onnxruntime-cpu",), repeats=2, warmup=0)
    assert [r.backend for r in only_onnx[0].runs] == ["onnxruntime-cpu"]
    with pytest.raises(EdgeExplorerError, match="unknown backend"):
        bench_models(tmp_path, ("tensorrt",), repeats=1, warmup=0)


def test_time_calls_discards_warmup_and_times_each_call():
    calls = []
    samples = time_calls(lambda: calls.append(1), repeats=7, warmup=3)
    assert len(calls) == 10 and samples.shape == (7,) and (samples >= 0).all()


def test_feeds_are_fixed_floats_of_each_inputs_shape_with_the_batch_set_to_one():
    specs = (
        TensorSpec("map", (1, 8, 8, 2), "int8", scale=0.01, zero_point=-128),  # quantized TFLite: fed as floats
        TensorSpec("last_action", (-1, 6), "float32"),
    )
    feed = feed_for(specs)
    assert feed["map"].dtype == np.float32 and np.abs(feed["map"]).max() <= 1.0
    np.testing.assert_array_equal(feed["map"], feed_for(specs)["map"])
    assert feed["last_action"].shape == (1, 6) and feed["last_action"].dtype == np.float32
