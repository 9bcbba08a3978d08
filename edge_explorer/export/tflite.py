"""Full-integer int8 TFLite through onnx2tf, run in its own converter environment, and the checks on the result.

onnx2tf (1.29.24, the last release for Python 3.11) pins numpy 1.26 and TensorFlow 2.19, so it lives in
``.venv-convert`` (``make convert-env``) and runs here as a subprocess: the runtime and training environment never
import TensorFlow. It converts NCHW to NHWC: a 4-D input ``[1, C, H, W]`` becomes ``[1, H, W, C]`` (the
predictor's runtime reads the layout from the declared shape), while inputs of other ranks are kept exactly as they
are (``-kat``: a 3-D ``[1, 237, 237]`` map is not a 1-D signal with 237 channels). Calibration uses the recipe's
observations (``-cind``, in the converted layout, mean 0 / std 1: the inputs are fed unnormalised) and the result
has int8 inputs and outputs (``-oiqt -iqd int8 -oqd int8``), per-channel or per-tensor weights as the recipe says.
TensorFlow's converter calibrates with its own min/max; the recipe's onnxruntime method applies to int8 ONNX.

After conversion:

* :func:`finalize_tflite` names the graph's input and output tensors after the ONNX ones (onnx2tf leaves
  ``serving_default_map:0`` / ``PartitionedCall:0``) and stores the exporter's metadata in the file's metadata
  table (``edge_explorer``: JSON), editing the flatbuffer with LiteRT's own schema bindings.
* :func:`xnnpack_coverage` loads the file under ai-edge-litert with its default XNNPACK delegate and counts the
  nodes the delegate took (a DELEGATE node replaces each partition; the nodes it covers are found by walking back
  from its outputs to its inputs). A graph XNNPACK refuses entirely — e.g. onnx2tf's known int8 MaxPool
  quantization mismatch — would run on LiteRT's reference kernels; that is an error, not a footnote.
* :func:`edgetpu_report` checks every op against Coral's documented Edge TPU operations and tensor rules
  (https://coral.ai/docs/edgetpu/models-intro/#supported-operations) and runs ``edgetpu_compiler`` when it is on
  PATH.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from collections import Counter
from collections.abc import Mapping, Sequence
from pathlib import Path

import flatbuffers
import numpy as np
from ai_edge_litert import schema_py_generated as tfl
from ai_edge_litert.interpreter import Interpreter

from edge_explorer.errors import EdgeExplorerError
from edge_explorer.export.calibration import Feed

PROJECT_ROOT = Path(__file__).resolve().parents[2]
CONVERT_ENV = PROJECT_ROOT / ".venv-convert"
METADATA_NAME = "edge_explorer"

# Coral's "Supported operations" table (Edge TPU compiler 16), as TFLite builtin operator names.
EDGETPU_OPS = frozenset(
    {
        "ADD", "AVERAGE_POOL_2D", "CONCATENATION", "CONV_2D", "DEPTHWISE_CONV_2D", "EXPAND_DIMS", "FULLY_CONNECTED",
        "L2_NORMALIZATION", "LOGISTIC", "LSTM", "MAXIMUM", "MAX_POOL_2D", "MEAN", "MINIMUM", "MUL", "PACK", "PAD",
        "PRELU", "QUANTIZE", "REDUCE_MAX", "REDUCE_MIN", "RELU", "RELU6", "RELU_N1_TO_1", "RESHAPE",
        "RESIZE_BILINEAR", "RESIZE_NEAREST_NEIGHBOR", "RSQRT", "SLICE", "SOFTMAX", "SPACE_TO_DEPTH", "SPLIT",
        "SQUARED_DIFFERENCE", "SQUEEZE", "STRIDED_SLICE", "SUB", "SUM", "TANH", "TRANSPOSE", "TRANSPOSE_CONV",
    }
)  # fmt: skip
_OP_NAMES = {v: k for k, v in vars(tfl.BuiltinOperator).items() if not k.startswith("_")}
_TYPE_NAMES = {v: k for k, v in vars(tfl.TensorType).items() if not k.startswith("_")}


class ConverterError(EdgeExplorerError):
    """The TFLite converter environment is missing or the conversion failed."""


def onnx2tf_executable(env: Path = CONVERT_ENV) -> Path:
    """The converter's entry point; a one-line error with the make target when the environment is missing."""
    exe = env / "bin" / "onnx2tf"
    if not exe.is_file():
        raise ConverterError(
            f"the TFLite converter environment is missing ({exe} not found); create it with `make convert-env` "
            "(onnx2tf + TensorFlow 2.19, ~2.6 GB), or drop tflite_int8 from the recipe's [formats] produce"
        )
    return exe


def tf_layout(array: np.ndarray) -> np.ndarray:
    """An ONNX-layout array in onnx2tf's layout: NCHW → NHWC for 4-D, unchanged otherwise (``-kat``)."""
    return np.ascontiguousarray(array.transpose(0, 2, 3, 1)) if array.ndim == 4 else array


def convert(
    onnx_path: Path,
    out_path: Path,
    feeds: Sequence[Feed],
    per_channel: bool,
    work_dir: Path,
    env: Path = CONVERT_ENV,
) -> Path:
    """onnx2tf full-integer conversion of ``onnx_path`` calibrated on ``feeds``; the int8 model goes to
    ``out_path``. The converter's log is kept in ``work_dir/onnx2tf.log``."""
    exe = onnx2tf_executable(env)
    work_dir.mkdir(parents=True, exist_ok=True)
    source = work_dir / onnx_path.name  # onnx2tf rewrites its input in place (onnxsim): hand it a copy
    shutil.copyfile(onnx_path, source)
    cmd = [str(exe), "-i", str(source), "-o", str(work_dir / "tf"), "-oiqt", "-b", "1"]
    cmd += ["-qt", "per-channel" if per_channel else "per-tensor", "-iqd", "int8", "-oqd", "int8"]
    keep = []
    for name in feeds[0]:
        npy = work_dir / f"calibration_{name}.npy"
        np.save(npy, np.concatenate([tf_layout(f[name]) for f in feeds], axis=0).astype(np.float32))
        cmd += ["-cind", name, str(npy), "[0.0]", "[1.0]"]
        if feeds[0][name].ndim != 4:
            keep.append(name)
    if keep:
        cmd += ["-kat", *keep]
    log_path = work_dir / "onnx2tf.log"
    # onnx2tf runs onnxsim as a command: the environment's bin/ must come first on PATH.
    run_env = {**os.environ, "PATH": f"{exe.parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    run_env.update({"TF_CPP_MIN_LOG_LEVEL": "2", "CUDA_VISIBLE_DEVICES": "-1", "PYTHONUNBUFFERED": "1"})
    with open(log_path, "w") as log:
        done = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT, env=run_env, check=False)
    produced = sorted((work_dir / "tf").glob("*_full_integer_quant.tflite"))
    if done.returncode != 0 or not produced:
        tail = log_path.read_text(errors="replace").strip().splitlines()[-1:] or ["no output"]
        raise ConverterError(f"onnx2tf failed (exit {done.returncode}): {tail[0][:300]} (full log: {log_path})")
    shutil.copyfile(produced[0], out_path)
    return out_path


def finalize_tflite(path: Path, input_names: Sequence[str], output_names: Sequence[str], metadata: Mapping) -> None:
    """Rename the I/O tensors after the ONNX names (matched through the signature) and embed ``metadata``."""
    model = tfl.ModelT.InitFromObj(tfl.Model.GetRootAsModel(path.read_bytes(), 0))
    graph = model.subgraphs[0]
    signature = model.signatureDefs[0] if model.signatureDefs else None
    if signature is None or len(signature.inputs) != len(input_names):
        raise ConverterError(f"{path.name}: expected one signature with inputs {list(input_names)}")
    by_key = {tm.name.decode(): tm for tm in signature.inputs}
    if set(by_key) != set(input_names):
        raise ConverterError(f"{path.name}: signature inputs {sorted(by_key)} differ from the ONNX {list(input_names)}")
    for name, tm in by_key.items():
        graph.tensors[tm.tensorIndex].name = name.encode()
    if len(signature.outputs) != len(output_names) or len(output_names) != 1:
        raise ConverterError(f"{path.name}: expected exactly one output, got {len(signature.outputs)}")
    out = signature.outputs[0]
    out.name = output_names[0].encode()
    graph.tensors[out.tensorIndex].name = output_names[0].encode()
    buffer = tfl.BufferT()
    buffer.data = np.frombuffer(json.dumps(dict(metadata), sort_keys=True).encode(), dtype=np.uint8)
    entry = tfl.MetadataT()
    entry.name, entry.buffer = METADATA_NAME.encode(), len(model.buffers)
    model.buffers.append(buffer)
    model.metadata = [*(model.metadata or []), entry]
    builder = flatbuffers.Builder(path.stat().st_size + 65536)
    builder.Finish(model.Pack(builder), file_identifier=b"TFL3")
    path.write_bytes(bytes(builder.Output()))


def read_metadata(path: Path) -> dict:
    """The exporter's metadata embedded by :func:`finalize_tflite` (empty when absent)."""
    model = tfl.Model.GetRootAsModel(path.read_bytes(), 0)
    for k in range(model.MetadataLength()):
        entry = model.Metadata(k)
        if entry.Name().decode() == METADATA_NAME:
            return json.loads(model.Buffers(entry.Buffer()).DataAsNumpy().tobytes())
    return {}


def xnnpack_coverage(path: Path) -> dict:
    """How much of the graph the XNNPACK delegate took, under ai-edge-litert's default op resolver."""
    interpreter = Interpreter(model_path=str(path), num_threads=1)
    interpreter.allocate_tensors()
    ops = interpreter._get_ops_details()  # every node: the original ones, then one DELEGATE node per partition
    producer = {int(t): op["index"] for op in ops if op["op_name"] != "DELEGATE" for t in op["outputs"]}
    covered: set[int] = set()
    delegates = [op for op in ops if op["op_name"] == "DELEGATE"]
    for delegate in delegates:
        stop = {int(t) for t in delegate["inputs"]}
        stack = [int(t) for t in delegate["outputs"]]
        while stack:
            node = producer.get(stack.pop())
            if node is None or node in covered:
                continue
            covered.add(node)
            stack += [int(t) for t in ops[node]["inputs"] if int(t) >= 0 and int(t) not in stop]
    originals = [op for op in ops if op["op_name"] != "DELEGATE"]
    on_cpu = Counter(op["op_name"] for op in originals if op["index"] not in covered)
    return {
        "delegated_nodes": len(covered),
        "total_nodes": len(originals),
        "partitions": len(delegates),
        "reference_kernel_ops": dict(on_cpu),
    }


def edgetpu_report(path: Path, work_dir: Path) -> dict:
    """Every op of ``path`` against the Edge TPU's supported operations and tensor rules; the compiler if present."""
    model = tfl.Model.GetRootAsModel(path.read_bytes(), 0)
    graph = model.Subgraphs(0)
    codes = [model.OperatorCodes(k) for k in range(model.OperatorCodesLength())]
    ops: list[str] = []
    tensor_problems: set[str] = set()
    for k in range(graph.OperatorsLength()):
        op = graph.Operators(k)
        code = codes[op.OpcodeIndex()]
        ops.append(_OP_NAMES.get(max(code.BuiltinCode(), code.DeprecatedBuiltinCode()), "CUSTOM"))
        for t in [*op.InputsAsNumpy(), *op.OutputsAsNumpy()]:
            if t < 0:
                continue
            tensor = graph.Tensors(int(t))
            if model.Buffers(tensor.Buffer()).DataLength() > 0:
                continue  # constants (weights, biases) are not subject to the activation tensor rules
            shape = [int(d) for d in tensor.ShapeAsNumpy()] if tensor.ShapeLength() else []
            kind = _TYPE_NAMES.get(tensor.Type(), str(tensor.Type()))
            name = tensor.Name().decode()
            if kind not in ("INT8", "UINT8"):
                tensor_problems.add(f"{name}: {kind} (the Edge TPU runs 8-bit quantized tensors only)")
            if len(shape) > 3 and any(d > 1 for d in shape[: len(shape) - 3]):
                tensor_problems.add(f"{name}: shape {shape} (> 3 dims with an outer dim > 1)")
            if tensor.ShapeSignatureLength() and any(d < 0 for d in tensor.ShapeSignatureAsNumpy()):
                tensor_problems.add(f"{name}: dynamic shape (sizes must be constant at compile time)")
    unsupported = [op for op in ops if op not in EDGETPU_OPS]
    first = next((i for i, op in enumerate(ops) if op not in EDGETPU_OPS), None)
    report = {
        "ops": dict(Counter(ops)),
        "unsupported_ops": dict(Counter(unsupported)),
        "cpu_fallback": (
            "none: every op and tensor is Edge TPU compatible"
            if first is None and not tensor_problems
            else f"from op #{first} ({ops[first]}) on, {len(ops) - first} of {len(ops)} ops run on the CPU "
            "(the compiler maps only the graph before the first unsupported op)"
            if first is not None
            else "tensor rules violated: see tensor_problems"
        ),
        "tensor_problems": sorted(tensor_problems)[:20],
        "source": "https://coral.ai/docs/edgetpu/models-intro/#supported-operations",
    }
    compiler = shutil.which("edgetpu_compiler")
    if compiler is None:
        report["compiler"] = "edgetpu_compiler is not installed on this host (x86-64 Debian package only); not compiled"
        return report
    out_dir = work_dir / "edgetpu"
    out_dir.mkdir(parents=True, exist_ok=True)
    done = subprocess.run([compiler, "-s", "-o", str(out_dir), str(path)], capture_output=True, text=True, check=False)
    report["compiler"] = f"edgetpu_compiler exit {done.returncode}"
    report["compiler_output"] = (done.stdout + done.stderr)[-4000:]
    compiled = sorted(out_dir.glob("*_edgetpu.tflite"))
    report["compiled"] = str(compiled[0]) if compiled and done.returncode == 0 else None
    return report


def converter_versions(env: Path = CONVERT_ENV) -> dict:
    """onnx2tf / TensorFlow versions of the converter environment, for the model card."""
    python = env / "bin" / "python"
    code = "import importlib.metadata as m;print(m.version('onnx2tf'), m.version('tensorflow'))"
    done = subprocess.run([str(python), "-c", code], capture_output=True, text=True, check=False)
    parts = done.stdout.split()
    if done.returncode != 0 or len(parts) != 2:
        return {"onnx2tf": "unknown", "tensorflow": "unknown"}
    return {"onnx2tf": parts[0], "tensorflow": parts[1]}
