"""Backends and the fallback chain on tiny models built here: ONNX with onnx.helper, TFLite with LiteRT's schema."""

from __future__ import annotations

import logging
import shutil
import subprocess
import sys
from pathlib import Path

import flatbuffers
import numpy as np
import onnx
import pytest
from ai_edge_litert import schema_py_generated as tfl
from onnx import TensorProto, helper

from edge_explorer.backends.base import BackendUnavailable, TensorSpec
from edge_explorer.backends.card import ArtifactCard, CardError, load_card, write_card
from edge_explorer.backends.chain import ModelLoadError, load_model
from edge_explorer.backends.edgetpu import EdgeTpuBackend
from edge_explorer.backends.litert_cpu import LiteRtCpuBackend, dequantize, quantize
from edge_explorer.backends.onnxruntime_cpu import OnnxRuntimeCpuBackend

X = np.array([[0.1, 0.5, -1.0, 2.0]], dtype=np.float32)
IN_SCALE, IN_ZERO = 0.05, -3
OUT_SCALE, OUT_ZERO = 0.1, 2


def write_onnx(path: Path) -> Path:
    """y = 2·x + 1 on a [1, 4] float input."""
    graph = helper.make_graph(
        [helper.make_node("Mul", ["x", "two"], ["twice"]), helper.make_node("Add", ["twice", "one"], ["y"])],
        "tiny",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 4])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 4])],
        [
            helper.make_tensor("two", TensorProto.FLOAT, [], [2.0]),
            helper.make_tensor("one", TensorProto.FLOAT, [], [1.0]),
        ],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)], ir_version=8)
    onnx.checker.check_model(model)
    onnx.save(model, path)
    return path


def write_tflite(path: Path, int8: bool) -> Path:
    """y = x + x (one ADD) on a [1, 4] tensor; int8 in and out with different scales when ``int8``."""

    def tensor(name: bytes, buffer: int, scale: float, zero: int) -> tfl.TensorT:
        t = tfl.TensorT()
        t.shape, t.name, t.buffer = [1, 4], name, buffer
        t.type = tfl.TensorType.INT8 if int8 else tfl.TensorType.FLOAT32
        if int8:
            t.quantization = tfl.QuantizationParametersT()
            t.quantization.scale, t.quantization.zeroPoint = [scale], [zero]
        return t

    code = tfl.OperatorCodeT()
    code.builtinCode = code.deprecatedBuiltinCode = tfl.BuiltinOperator.ADD
    code.version = 1
    op = tfl.OperatorT()
    op.opcodeIndex, op.inputs, op.outputs = 0, [0, 0], [1]
    op.builtinOptionsType, op.builtinOptions = tfl.BuiltinOptions.AddOptions, tfl.AddOptionsT()
    graph = tfl.SubGraphT()
    graph.tensors = [tensor(b"x", 1, IN_SCALE, IN_ZERO), tensor(b"y", 2, OUT_SCALE, OUT_ZERO)]
    graph.inputs, graph.outputs, graph.operators, graph.name = [0], [1], [op], b"main"
    model = tfl.ModelT()
    model.version, model.description = 3, b"tiny test model"
    model.operatorCodes, model.subgraphs = [code], [graph]
    model.buffers = [tfl.BufferT(), tfl.BufferT(), tfl.BufferT()]
    builder = flatbuffers.Builder(1024)
    builder.Finish(model.Pack(builder), file_identifier=b"TFL3")
    path.write_bytes(bytes(builder.Output()))
    return path


def card_entry(path: Path, fmt: str, precision: str, dtype: str) -> ArtifactCard:
    spec = [TensorSpec("x", (1, 4), dtype)], [TensorSpec("y", (1, 4), dtype)]
    return ArtifactCard.describe(path, fmt, *spec, precision=precision)


@pytest.fixture
def model_dir(tmp_path: Path) -> Path:
    """A 'predictor' folder with fp32 ONNX, int8 TFLite and a (CPU-only) file posing as its Edge TPU build."""
    folder = tmp_path / "predictor"
    folder.mkdir()
    onnx_path = write_onnx(folder / "predictor_fp32.onnx")
    tflite_path = write_tflite(folder / "predictor_int8.tflite", int8=True)
    edgetpu_path = shutil.copy(tflite_path, folder / "predictor_int8_edgetpu.tflite")
    write_card(
        folder / "card.json",
        "predictor",
        [
            card_entry(onnx_path, "onnx", "fp32", "float32"),
            card_entry(tflite_path, "tflite", "int8", "int8"),
            card_entry(Path(edgetpu_path), "edgetpu_tflite", "int8", "int8"),
        ],
    )
    return folder


def test_onnxruntime_round_trip(tmp_path: Path) -> None:
    backend = OnnxRuntimeCpuBackend()
    backend.load(write_onnx(tmp_path / "m.onnx"))
    assert backend.inputs == (TensorSpec("x", (1, 4), "float32"),)
    assert backend.outputs == (TensorSpec("y", (1, 4), "float32"),)
    out = backend.run({"x": X})
    np.testing.assert_allclose(out["y"], 2 * X + 1, rtol=1e-6)
    assert out["y"].dtype == np.float32


def test_litert_float_round_trip(tmp_path: Path) -> None:
    backend = LiteRtCpuBackend()
    backend.load(write_tflite(tmp_path / "m.tflite", int8=False))
    assert backend.inputs[0] == TensorSpec("x", (1, 4), "float32")
    np.testing.assert_allclose(backend.run({"x": X})["y"], 2 * X, rtol=1e-6)


def test_litert_int8_quantizes_inputs_and_dequantizes_outputs(tmp_path: Path) -> None:
    backend = LiteRtCpuBackend()
    backend.load(write_tflite(tmp_path / "m.tflite", int8=True))
    spec_in, spec_out = backend.inputs[0], backend.outputs[0]
    assert (spec_in.dtype, spec_in.zero_point, spec_out.zero_point) == ("int8", IN_ZERO, OUT_ZERO)
    assert spec_in.scale == pytest.approx(IN_SCALE) and spec_out.scale == pytest.approx(OUT_SCALE)
    y = backend.run({"x": X})["y"]
    assert y.dtype == np.float32
    np.testing.assert_allclose(y, 2 * X, atol=OUT_SCALE / 2 + 2 * IN_SCALE / 2)  # output step + doubled input step


def test_quantize_saturates_and_dequantize_inverts() -> None:
    spec = TensorSpec("x", (3,), "int8", scale=0.5, zero_point=10)
    q = quantize(np.array([0.0, 1000.0, -1000.0]), spec)
    np.testing.assert_array_equal(q, [10, 127, -128])
    np.testing.assert_allclose(dequantize(np.array([10, 12], np.int8), spec), [0.0, 1.0])


def test_wrong_input_shape_or_name_is_a_clear_error(tmp_path: Path) -> None:
    backend = OnnxRuntimeCpuBackend()
    backend.load(write_onnx(tmp_path / "m.onnx"))
    with pytest.raises(ValueError, match=r"input 'x' has shape \(1, 3\)"):
        backend.run({"x": np.zeros((1, 3), np.float32)})
    with pytest.raises(ValueError, match=r"the model takes \['x'\]"):
        backend.run({"image": X})


def test_edgetpu_without_device_says_so(tmp_path: Path) -> None:
    model = write_tflite(tmp_path / "m_edgetpu.tflite", int8=True)
    with pytest.raises(BackendUnavailable, match=r"no Edge TPU present: libedgetpu\.so\.1"):
        EdgeTpuBackend().load(model)
    with pytest.raises(BackendUnavailable, match="not compiled for the Edge TPU"):
        EdgeTpuBackend().load(shutil.copy(model, tmp_path / "plain.tflite"))


def test_chain_picks_first_working_backend_and_logs_why(model_dir: Path, caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.INFO, logger="edge_explorer.backends.chain"):
        loaded = load_model(model_dir, ("edgetpu", "litert-cpu", "onnxruntime-cpu"))
    assert loaded.backend.name == "litert-cpu" and loaded.artifact.name == "predictor_int8.tflite"
    assert loaded.report.startswith("predictor: litert-cpu on predictor_int8.tflite (edgetpu skipped: no Edge TPU")
    assert loaded.report.endswith("sha256 ok)")
    assert caplog.messages == [loaded.report]
    np.testing.assert_allclose(loaded.run({"x": X})["y"], 2 * X, atol=0.2)


def test_chain_skips_corrupted_artifact_naming_the_sha_mismatch(model_dir: Path) -> None:
    tflite = model_dir / "predictor_int8.tflite"
    data = bytearray(tflite.read_bytes())
    data[-1] ^= 0xFF
    tflite.write_bytes(bytes(data))
    loaded = load_model(model_dir, ("litert-cpu", "onnxruntime-cpu"))
    assert loaded.backend.name == "onnxruntime-cpu"
    assert "litert-cpu skipped: predictor_int8.tflite: sha256 mismatch" in loaded.report
    np.testing.assert_allclose(loaded.run({"x": X})["y"], 2 * X + 1, rtol=1e-6)


def test_chain_raises_when_nothing_works(model_dir: Path) -> None:
    (model_dir / "predictor_fp32.onnx").write_bytes(b"not a model")
    (model_dir / "predictor_int8.tflite").unlink()
    with pytest.raises(ModelLoadError) as err:
        load_model(model_dir, ("edgetpu", "litert-cpu", "onnxruntime-cpu"))
    message = str(err.value)
    assert "no Edge TPU present" in message
    assert "predictor_int8.tflite: missing" in message
    assert "predictor_fp32.onnx: sha256 mismatch" in message


def test_chain_checks_card_shapes_and_prefers_the_asked_precision(model_dir: Path) -> None:
    fp32 = write_tflite(model_dir / "predictor_fp32.tflite", int8=False)
    card = load_card(model_dir)
    artifacts = [*card.artifacts.values(), card_entry(fp32, "tflite", "fp32", "float32")]
    write_card(model_dir / "card.json", "predictor", artifacts)
    assert load_model(model_dir, ("litert-cpu",), precision="fp32").artifact.name == "predictor_fp32.tflite"
    assert load_model(model_dir, ("litert-cpu",), precision="int8").artifact.name == "predictor_int8.tflite"

    wrong = ArtifactCard.describe(
        fp32, "tflite", [TensorSpec("x", (1, 8), "float32")], [TensorSpec("y", (1, 4), "float32")]
    )
    write_card(model_dir / "card.json", "predictor", [wrong])
    with pytest.raises(ModelLoadError, match=r"input 'x' is \[1, 4\] float32, the card says \[1, 8\] float32"):
        load_model(model_dir, ("litert-cpu",))


def test_malformed_cards_are_rejected_with_the_reason(tmp_path: Path) -> None:
    card = tmp_path / "card.json"
    card.write_text("{")
    with pytest.raises(CardError, match="not valid JSON"):
        load_card(card)
    card.write_text('{"artifacts": {"m.onnx": {"sha256": "abc", "format": "onnx", "inputs": [], "outputs": []}}}')
    with pytest.raises(CardError, match="'sha256' must be 64 lowercase hex digits"):
        load_card(card)
    with pytest.raises(ModelLoadError, match="unknown backend"):
        load_model(card, ("tensorrt",))


def test_runtime_path_imports_no_training_framework() -> None:
    """The modules of this runtime path load without torch, stable-baselines3 or TensorFlow (docs/design.md §2)."""
    code = (
        "import sys\n"
        "import edge_explorer.backends.chain, edge_explorer.runtime.depth_sources, edge_explorer.runtime.daemon\n"
        "import edge_explorer.vehicle.camera, edge_explorer.sim.vehicle, edge_explorer.sim.depth_source\n"
        "heavy = sorted(m for m in ('torch', 'tensorflow', 'stable_baselines3') if m in sys.modules)\n"
        "assert not heavy, heavy\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)
