"""Why the self-imitated policy's int8 ONNX failed the goal gate (90.1 %) while its TFLite passed (session 25):
onnxruntime variants of the same fp32 graph, judged like the export's gate on the recipe's own observations (cached
in runs/s25/q8/ after the first run). Run from the project root: python docs/policy/session25/onnx_int8_probe.py"""

import pickle
from pathlib import Path

import onnx
import torch
from onnxruntime.quantization import CalibrationMethod, QuantFormat, QuantType, quantize_static
from onnxruntime.quantization.shape_inference import quant_pre_process

from edge_explorer.backends.onnxruntime_cpu import OnnxRuntimeCpuBackend
from edge_explorer.export import gates, onnx_formats, pipeline
from edge_explorer.export.networks import load_network
from edge_explorer.export.recipe import load_recipe

torch.set_num_threads(1)
recipe = load_recipe("quantize/policy.toml")
network = load_network(recipe)
cache = Path("runs/s25/q8/obs.pkl")
cache.parent.mkdir(parents=True, exist_ok=True)
if cache.exists():
    obs = pickle.loads(cache.read_bytes())
else:
    obs = pipeline.collect_observations(recipe, network)
    cache.write_bytes(pickle.dumps(obs))
net = network.prepare([network.cast(f) for f in obs.calibration])
held = [net.cast(f) for f in obs.held_back]
cal = [net.cast(f) for f in obs.calibration]
ref = pipeline.torch_outputs(net, held)
dec = pipeline.torch_outputs(net, held, net.decision_reference)
fp32 = Path("runs/s25/q8/fp32.onnx")
onnx_formats.export_fp32(net, fp32)
m = onnx.load(str(fp32))
print([(n.op_type, n.name) for n in m.graph.node][-12:])


def score(path, label):
    b = OnnxRuntimeCpuBackend(1)
    b.load(path)
    outs = pipeline.backend_outputs(b, held, ref)
    g = gates.goal_gate(dec, outs, obs.masks, {"min_top1_agreement": 0.98})
    print(label, g.summary, flush=True)


score(fp32, "fp32")
prepared = Path("runs/s25/q8/prep.onnx")
quant_pre_process(str(fp32), str(prepared), skip_symbolic_shape=True)


def q(label, **kw):
    out = Path(f"runs/s25/q8/{label}.onnx")
    args = dict(
        quant_format=QuantFormat.QDQ,
        activation_type=QuantType.QInt8,
        weight_type=QuantType.QInt8,
        per_channel=True,
        calibrate_method=CalibrationMethod.MinMax,
        extra_options={"CalibTensorRangeSymmetric": False},
    )
    args.update(kw)
    quantize_static(str(prepared), str(out), onnx_formats.FeedReader(cal), **args)
    score(out, label)


q("base")
last = [n.name for n in onnx.load(str(prepared)).graph.node if n.op_type == "Conv"][-1]
print("last conv", last)
q("excl_last_conv", nodes_to_exclude=[last])
q("uint8_act", activation_type=QuantType.QUInt8)
q("per_tensor", per_channel=False)
