"""The ONNX graph rewrites: quantizing a ``Where`` of constants folds into them; a constant-index ``Gather`` becomes
``Slice`` + ``Squeeze``."""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort
from onnx import TensorProto, helper, numpy_helper

from edge_explorer.export.onnx_formats import fold_quantize_into_where, gather_to_slice


def where_quantized(extra_consumer: bool = False) -> onnx.ModelProto:
    """mask → Where(mask, 1.0, 0.0) → Quantize (1/255, −128, int8) → Dequantize → y; optionally y2 = Where's output."""
    initializers = [
        numpy_helper.from_array(np.array(1.0, np.float32), "one"),
        numpy_helper.from_array(np.array(0.0, np.float32), "zero"),
        numpy_helper.from_array(np.array(1 / 255, np.float32), "scale"),
        numpy_helper.from_array(np.array(-128, np.int8), "zero_point"),
    ]
    nodes = [
        helper.make_node("Where", ["mask", "one", "zero"], ["chosen"]),
        helper.make_node("QuantizeLinear", ["chosen", "scale", "zero_point"], ["q"]),
        helper.make_node("DequantizeLinear", ["q", "scale", "zero_point"], ["y"]),
    ]
    outputs = [helper.make_tensor_value_info("y", TensorProto.FLOAT, [2, 3])]
    if extra_consumer:
        nodes.append(helper.make_node("Identity", ["chosen"], ["y2"]))
        outputs.append(helper.make_tensor_value_info("y2", TensorProto.FLOAT, [2, 3]))
    graph = helper.make_graph(
        nodes, "g", [helper.make_tensor_value_info("mask", TensorProto.BOOL, [2, 3])], outputs, initializers
    )
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)], ir_version=9)


def run(model: onnx.ModelProto, mask: np.ndarray) -> np.ndarray:
    return ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"]).run(
        ["y"], {"mask": mask}
    )[0]


def test_quantizing_a_where_of_constants_folds_into_uint8_constants_with_the_same_values():
    mask = np.array([[True, False, True], [False, False, True]])
    model = where_quantized()
    before = run(model, mask)
    assert fold_quantize_into_where(model) == 1
    onnx.checker.check_model(model, full_check=True)
    assert [n.op_type for n in model.graph.node] == ["Where", "DequantizeLinear"]
    where = model.graph.node[0]
    branches = {t.name: numpy_helper.to_array(t) for t in model.graph.initializer}
    assert {"one", "zero", "zero_point"}.isdisjoint(branches)  # gone, not left unused
    one, zero = (branches[name] for name in where.input[1:])
    assert one.dtype == np.uint8 and (int(one), int(zero)) == (255, 0)  # int8 127 / −128 shifted as onnxruntime does
    assert np.array_equal(run(model, mask), before) and np.array_equal(before, mask.astype(np.float32))


def test_a_where_that_feeds_something_else_is_left_alone():
    model = where_quantized(extra_consumer=True)
    assert fold_quantize_into_where(model) == 0
    assert [n.op_type for n in model.graph.node] == ["Where", "QuantizeLinear", "DequantizeLinear", "Identity"]


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
