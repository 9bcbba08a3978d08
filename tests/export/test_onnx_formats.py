"""The ONNX graph rewrite: a constant-index ``Gather`` becomes ``Slice`` + ``Squeeze``."""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort
from onnx import TensorProto, helper, numpy_helper

from edge_explorer.export.onnx_formats import gather_to_slice, quantize_int8
from edge_explorer.export.recipe import QuantizationConfig


def test_a_constant_index_gather_becomes_slice_and_squeeze_with_the_same_values():
    x = np.arange(2 * 3 * 4, dtype=np.float32).reshape(2, 3, 4)
    for index in (0, 2, -1):
        graph = helper.make_graph(
            [helper.make_node("Gather", ["x", "i"], ["y"], axis=1)],
            "gather",
            [helper.make_tensor_value_info("x", TensorProto.FLOAT, [2, 3, 4])],
            [helper.make_tensor_value_info("y", TensorProto.FLOAT, [2, 4])],
            [numpy_helper.from_array(np.array(index, np.int64), "i")],
        )
        model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
        assert gather_to_slice(model) == 1
        onnx.checker.check_model(model, full_check=True)
        assert [n.op_type for n in model.graph.node] == ["Slice", "Squeeze"]
        assert "i" not in {t.name for t in model.graph.initializer}
        session = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
        np.testing.assert_array_equal(session.run(None, {"x": x})[0], x[:, index])


def _two_convs(path) -> None:
    """x (1, 2, 4, 4) -> Conv 2→3 -> Relu -> Conv 3→1: a graph whose last Conv the recipe can keep float."""
    rng = np.random.default_rng(0)
    w1, w2 = (numpy_helper.from_array(rng.normal(size=s).astype(np.float32), n) for n, s in
              (("w1", (3, 2, 1, 1)), ("w2", (1, 3, 1, 1))))  # fmt: skip
    graph = helper.make_graph(
        [
            helper.make_node("Conv", ["x", "w1"], ["a"], name="first"),
            helper.make_node("Relu", ["a"], ["b"], name="relu"),
            helper.make_node("Conv", ["b", "w2"], ["y"], name="last"),
        ],
        "two_convs",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 2, 4, 4])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 1, 4, 4])],
        [w1, w2],
    )
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)]), str(path))


def _float_conv_weights(path) -> set[str]:
    """Conv nodes whose weight input comes straight from a float initializer (not through DequantizeLinear)."""
    model = onnx.load(str(path))
    initializers = {t.name for t in model.graph.initializer}
    return {n.name for n in model.graph.node if n.op_type == "Conv" and n.input[1] in initializers}


def test_onnx_float_output_conv_leaves_only_the_last_conv_in_float(tmp_path):
    _two_convs(tmp_path / "fp32.onnx")
    rng = np.random.default_rng(1)
    feeds = [{"x": rng.normal(size=(1, 2, 4, 4)).astype(np.float32)} for _ in range(8)]
    for keep_float, expected in ((False, set()), (True, {"last"})):
        out = tmp_path / f"int8_{keep_float}.onnx"
        quantize_int8(tmp_path / "fp32.onnx", out, feeds, QuantizationConfig(onnx_float_output_conv=keep_float))
        assert _float_conv_weights(out) == expected
        session = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
        assert session.run(None, feeds[0])[0].shape == (1, 1, 4, 4)
