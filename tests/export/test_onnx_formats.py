"""The ONNX graph rewrite: a constant-index ``Gather`` becomes ``Slice`` + ``Squeeze``."""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort
from onnx import TensorProto, helper, numpy_helper

from edge_explorer.export.onnx_formats import gather_to_slice


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
