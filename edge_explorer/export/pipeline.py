"""One export: recipe → calibration rollouts → ONNX fp32 → int8 ONNX → int8 TFLite → gates → model card.

Everything is written to a temporary folder beside the model folder first. Only when every produced format passes
its gate are the files moved into ``<out>/<name>/`` and ``card.json`` updated (its other keys — training,
evaluation — are kept; ``artifacts`` and ``export`` are replaced). A failed gate leaves the previous artifacts and
card untouched.

Each format is loaded through the same backends the daemon uses (:mod:`edge_explorer.backends`), run on the
held-back observations, gated (:mod:`edge_explorer.export.gates`) and timed on one thread (median of the recipe's
``repeats`` after warm-up), beside torch fp32 eager on the same input in the same run.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from importlib.metadata import version
from pathlib import Path

import numpy as np
import torch

from edge_explorer.backends.base import InferenceBackend
from edge_explorer.backends.card import CARD_FILE, ArtifactCard
from edge_explorer.backends.litert_cpu import LiteRtCpuBackend
from edge_explorer.backends.onnxruntime_cpu import OnnxRuntimeCpuBackend
from edge_explorer.export import gates as gate_fns
from edge_explorer.export import onnx_formats, tflite
from edge_explorer.export.calibration import (
    Feed,
    Observations,
    goal_observations,
    predictor_observations,
)
from edge_explorer.export.networks import ExportNetwork, load_network
from edge_explorer.export.recipe import Recipe, check_inputs_exist

FP32_PARITY_TOLERANCE = 1e-3  # max |Δ| of raw outputs, fp32 ONNX vs torch
WARMUP_RUNS = 3
FORMAT_LABELS = {"torch_fp32": "torch fp32 (eager)", "onnx_fp32": "ONNX fp32", "onnx_int8": "ONNX int8 (QDQ)",
                 "tflite_int8": "TFLite int8 (full integer)"}  # fmt: skip


@dataclass
class FormatResult:
    """One row of the format table."""

    format: str
    file: str
    size_bytes: int
    latency_ms: float
    gate: gate_fns.GateResult | None
    card: ArtifactCard | None = None
    details: dict = field(default_factory=dict)

    @property
    def passed(self) -> bool:
        return self.gate is None or self.gate.passed


@dataclass
class ExportReport:
    recipe: Recipe
    out_dir: Path
    rows: list[FormatResult]
    card: dict

    @property
    def passed(self) -> bool:
        return all(r.passed for r in self.rows)

    def failures(self) -> list[str]:
        return [f"{r.format}: {'; '.join(r.gate.failures)}" for r in self.rows if r.gate and not r.gate.passed]

    def table(self) -> str:
        """Format | File | Size | Latency (ms, 1 thread) | Accuracy vs fp32 | Status, as aligned text."""
        head = ("Format", "File", "Size", "Latency (ms, 1 thread)", "Accuracy vs fp32", "Status")
        lines = [head]
        for r in self.rows:
            status = "reference" if r.gate is None else ("pass" if r.gate.passed else "FAIL")
            accuracy = "—" if r.gate is None else r.gate.summary
            lines.append(
                (FORMAT_LABELS[r.format], r.file, _size(r.size_bytes), f"{r.latency_ms:.2f}", accuracy, status)
            )
        widths = [max(len(row[k]) for row in lines) for k in range(len(head))]
        fmt = lambda row: " | ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True))  # noqa: E731
        return "\n".join([fmt(lines[0]), "-+-".join("-" * w for w in widths), *(fmt(row) for row in lines[1:])])

    def to_json(self) -> dict:
        return {"recipe": str(self.recipe.path), "out_dir": str(self.out_dir), "passed": self.passed,
                "failures": self.failures(), "card": self.card}  # fmt: skip


def _size(n: int) -> str:
    return f"{n / 1e6:.2f} MB" if n >= 1e5 else f"{n / 1e3:.1f} kB"


def median_latency_ms(run: Callable[[], object], repeats: int) -> float:
    for _ in range(WARMUP_RUNS):
        run()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        run()
        times.append(1e3 * (time.perf_counter() - t0))
    return statistics.median(times)


def in_layout(feed: Feed, backend: InferenceBackend) -> dict[str, np.ndarray]:
    """A feed (ONNX layout) in the backend's declared input layout (NHWC for onnx2tf's 4-D inputs)."""
    out = {}
    for spec in backend.inputs:
        value = feed[spec.name]
        out[spec.name] = value if spec.accepts_shape(value.shape) else tflite.tf_layout(value)
    return out


def backend_outputs(backend: InferenceBackend, feeds: Sequence[Feed], like: Sequence[np.ndarray]) -> list[np.ndarray]:
    """The backend's one output for every feed, back in the torch layout of ``like``."""
    name = backend.outputs[0].name
    outs = []
    for feed, ref in zip(feeds, like, strict=True):
        out = backend.run(in_layout(feed, backend))[name]
        if out.shape != ref.shape and out.ndim == 4:
            out = out.transpose(0, 3, 1, 2)
        outs.append(out.reshape(ref.shape))
    return outs


def torch_outputs(
    network: ExportNetwork, feeds: Sequence[Feed], module: torch.nn.Module | None = None
) -> list[np.ndarray]:
    module = network.module if module is None else module
    with torch.no_grad():
        return [module(*(torch.from_numpy(f[n]) for n in network.inputs)).numpy() for f in feeds]


def collect_observations(recipe: Recipe, network: ExportNetwork) -> Observations:
    """The recipe's calibration and held-back observations (policy rollouts act with the fp32 network; the thres
    map's predictor is loaded as ``bench explore --predictor`` loads it)."""
    if network.kind == "predictor":
        return predictor_observations(recipe.calibration, next(iter(network.inputs)))

    module = network.decision_reference or network.module

    def scores(obs: dict[str, np.ndarray]) -> np.ndarray:
        with torch.no_grad():
            args = (torch.from_numpy(np.asarray(obs[n], dtype=np.float32)[None]) for n in network.inputs)
            return module(*args).numpy()

    predictor = None
    if recipe.calibration.predictor is not None:
        from edge_explorer.learn.loaders import load_predictor

        predictor = load_predictor(str(recipe.calibration.predictor))
    return goal_observations(recipe.calibration, lambda obs, mask: gate_fns.masked_argmax(scores(obs), mask),
                             predictor)  # fmt: skip


def graph_cost(onnx_path: Path, network: ExportNetwork) -> dict:
    """MACs and parameters counted on the exported graph by onnx-tool."""
    import onnx_tool

    model = onnx_tool.Model(str(onnx_path))
    model.graph.shape_infer({name: np.zeros(shape, np.float32) for name, shape in network.inputs.items()})
    model.graph.profile()
    macs = model.graph.macs  # onnx-tool 1.x: [multiply-accumulates, sparse-skipped]
    return {
        "macs": int(macs[0] if isinstance(macs, list | tuple) else macs),
        "params": int(model.graph.params),
        "counted_by": f"onnx-tool {version('onnx-tool')} (graph profile; params include constants, e.g. Resize scales)",
    }


def run_export(
    recipe: Recipe,
    out_root: Path,
    network: ExportNetwork | None = None,
    convert_env: Path = tflite.CONVERT_ENV,
    log: Callable[[str], None] = print,
) -> ExportReport:
    """Run the recipe; artifacts land in ``out_root/<folder>/`` only if every gate passes (see module docstring)."""
    if network is None:
        check_inputs_exist(recipe)
    if "tflite_int8" in recipe.formats:
        tflite.onnx2tf_executable(convert_env)  # fail before any work when the converter env is missing
    network = network or load_network(recipe)
    previous_threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        observations = collect_observations(recipe, network)
        if network.prepare is not None:
            network = network.prepare([network.cast(f) for f in observations.calibration])
        out_root.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=out_root, prefix=f".{recipe.name}-export-") as tmp:
            out_dir = out_root / recipe.out_folder
            report = _export_in(Path(tmp), recipe, out_dir, network, observations, convert_env, log)
            if report.passed:
                _install(Path(tmp), report)
    finally:
        torch.set_num_threads(previous_threads)
    return report


def _export_in(
    tmp: Path,
    recipe: Recipe,
    out_dir: Path,
    network: ExportNetwork,
    obs: Observations,
    convert_env: Path,
    log: Callable[[str], None],
) -> ExportReport:
    name = recipe.name
    held, calibration = ([network.cast(f) for f in feeds] for feeds in (obs.held_back, obs.calibration))
    reference = torch_outputs(network, held)
    # the decisions every format is judged against: the unwrapped network's, where the export computes an
    # equivalent function (the goal policy's windowed scores)
    decisions = (
        reference if network.decision_reference is None else torch_outputs(network, held, network.decision_reference)
    )

    def recipe_gate(outputs: list[np.ndarray]) -> gate_fns.GateResult:
        if network.kind == "predictor":
            return gate_fns.predictor_gate(reference, outputs, obs.maps, recipe.gates)
        return gate_fns.goal_gate(decisions, outputs, obs.masks, recipe.gates)

    example = [torch.from_numpy(held[0][n]) for n in network.inputs]
    with torch.no_grad():
        torch_ms = median_latency_ms(lambda: network.module(*example), recipe.latency_repeats)
    checkpoint_size = recipe.checkpoint.stat().st_size if recipe.checkpoint.is_file() else 0
    rows = [FormatResult("torch_fp32", recipe.checkpoint.name, checkpoint_size, torch_ms, None)]
    log(f"torch fp32 eager: {torch_ms:.2f} ms (1 thread)")

    def measure(fmt: str, path: Path, backend: InferenceBackend, precision: str, make_gate) -> FormatResult:
        backend.load(path)
        outputs = backend_outputs(backend, held, reference)
        feed = in_layout(held[0], backend)
        latency = median_latency_ms(lambda: backend.run(feed), recipe.latency_repeats)
        card = ArtifactCard.describe(path, "onnx" if fmt.startswith("onnx") else "tflite", backend.inputs,
                                     backend.outputs, precision)  # fmt: skip
        result = FormatResult(fmt, path.name, path.stat().st_size, latency, make_gate(outputs), card)
        log(f"{FORMAT_LABELS[fmt]}: {latency:.2f} ms, {result.gate.summary} ({'pass' if result.passed else 'FAIL'})")
        return result

    fp32_path = tmp / f"{name}_fp32.onnx"
    log(f"exporting {fp32_path.name} (torch.onnx dynamo, opset {onnx_formats.OPSET})")
    onnx_formats.export_fp32(network, fp32_path)
    cost = graph_cost(fp32_path, network)
    rows.append(measure("onnx_fp32", fp32_path, OnnxRuntimeCpuBackend(1), "fp32",
                        lambda outs: gate_fns.parity_gate(reference, outs, FP32_PARITY_TOLERANCE)))  # fmt: skip
    if network.kind == "policy" and network.decision_reference is not None:
        # the exported function must choose exactly the unwrapped network's goals (torch fp32, held-back decisions)
        parity = gate_fns.goal_gate(decisions, reference, obs.masks, {"min_top1_agreement": 1.0})
        fp32_row = rows[-1]
        fp32_row.details["decision_parity_vs_unwrapped_net"] = parity.figures["top1_agreement"]
        log(f"exported function vs the unwrapped net (torch fp32): {parity.summary}")
        if not parity.passed:
            fp32_row.gate = gate_fns.GateResult(False, fp32_row.gate.figures, fp32_row.gate.summary,
                                                (*fp32_row.gate.failures, *parity.failures))  # fmt: skip

    if "onnx_int8" in recipe.formats:
        int8_path = tmp / f"{name}_int8.onnx"
        log(f"quantizing {int8_path.name} ({recipe.quantization.method}, {len(calibration)} observations)")
        onnx_formats.quantize_int8(fp32_path, int8_path, calibration, recipe.quantization)
        row = measure("onnx_int8", int8_path, OnnxRuntimeCpuBackend(1), "int8", recipe_gate)
        if not row.passed:
            row.details["qdq_error_report"] = onnx_formats.qdq_error_report(fp32_path, int8_path, held[:8])
            log("int8 ONNX gate failed; worst tensors (SQNR dB vs fp32, qdq_loss_debug):")
            for r in row.details["qdq_error_report"][:5]:
                log(f"  {r['tensor']}: {r['xmodel_sqnr_db']:.1f} dB (own QDQ {r['qdq_sqnr_db']:.1f} dB)")
        rows.append(row)

    if "tflite_int8" in recipe.formats:
        tfl_path = tmp / f"{name}_int8.tflite"
        log(f"converting {tfl_path.name} from {fp32_path.name} with onnx2tf (full integer, {len(calibration)} "
            "observations)")  # fmt: skip
        tflite.convert(fp32_path, tfl_path, calibration, recipe.quantization.per_channel, tmp / "onnx2tf",
                       convert_env)  # fmt: skip
        tflite.finalize_tflite(tfl_path, list(network.inputs), network.outputs, network.metadata)
        xnnpack = tflite.xnnpack_coverage(tfl_path)
        row = measure("tflite_int8", tfl_path, LiteRtCpuBackend(1), "int8", recipe_gate)
        row.details["xnnpack"] = xnnpack
        row.details["edgetpu"] = tflite.edgetpu_report(tfl_path, tmp / "edgetpu")
        log(f"XNNPACK took {xnnpack['delegated_nodes']}/{xnnpack['total_nodes']} nodes in {xnnpack['partitions']} "
            f"partition(s); on LiteRT's own kernels: {xnnpack['reference_kernel_ops'] or 'nothing'}")  # fmt: skip
        log(f"Edge TPU: {row.details['edgetpu']['cpu_fallback']}; {row.details['edgetpu']['compiler']}")
        if xnnpack["delegated_nodes"] == 0:
            row.gate = gate_fns.GateResult(False, row.gate.figures, row.gate.summary,
                                           (*row.gate.failures, "XNNPACK refused the whole graph"))  # fmt: skip
        row.details["converter"] = tflite.converter_versions(convert_env)
        rows.append(row)

    report = ExportReport(recipe, out_dir, rows, {})
    report.card = _card(report, network, obs, cost, torch_ms)
    return report


def _card(report: ExportReport, network: ExportNetwork, obs: Observations, cost: dict, torch_ms: float) -> dict:
    """The model card with ``artifacts`` and ``export`` from this run; other keys of an existing card kept."""
    recipe = report.recipe
    card_path = report.out_dir / CARD_FILE
    card = json.loads(card_path.read_text()) if card_path.is_file() else {"model": recipe.name}
    artifacts = {}
    formats = {}
    for row in report.rows:
        entry = {"size_bytes": row.size_bytes, "latency_ms_1thread": round(row.latency_ms, 3)}
        if row.gate is not None:
            entry["accuracy_vs_fp32"] = row.gate.figures
            entry["gate_passed"] = row.gate.passed
        entry.update(row.details)
        formats[row.format] = {"file": row.file, **entry}
        if row.card is not None:
            artifacts[row.file] = {**row.card.to_json(), "size_bytes": row.size_bytes,
                                   "latency_ms_1thread": round(row.latency_ms, 3)}  # fmt: skip
    tflite_row = next((r for r in report.rows if r.format == "tflite_int8"), None)
    card["artifacts"] = artifacts
    card["export"] = {
        "date_utc": datetime.now(UTC).isoformat(timespec="seconds"),
        "recipe": {"file": str(recipe.path), "text": recipe.path.read_text() if recipe.path.is_file() else None},
        "metadata": network.metadata,
        "graph": cost,
        "calibration": {
            **obs.description,
            "method": recipe.quantization.method,
            "per_channel": recipe.quantization.per_channel,
            "tflite_calibration": "TensorFlow Lite converter min/max over the same observations",
        },  # fmt: skip
        "gates": dict(recipe.gates),
        "formats": formats,
        "latency_note": f"single thread, median of {recipe.latency_repeats} runs after {WARMUP_RUNS} warm-up, "
        f"this host ({platform.machine()}, {os.cpu_count()} shared cores, load {os.getloadavg()[0]:.1f})",
        "torch_fp32_eager_ms": round(torch_ms, 3),
        "tflite_int8_vs_torch_fp32": round(tflite_row.latency_ms / torch_ms, 3) if tflite_row else None,
    }
    return card


def _install(tmp: Path, report: ExportReport) -> None:
    """Move the passed artifacts into the model folder, then write the card (atomically, last)."""
    report.out_dir.mkdir(parents=True, exist_ok=True)
    for row in report.rows:
        if row.card is not None:
            os.replace(tmp / row.file, report.out_dir / row.file)
    staged = tmp / CARD_FILE
    staged.write_text(json.dumps(report.card, indent=1, default=_json_default) + "\n")
    os.replace(staged, report.out_dir / CARD_FILE)


def _json_default(obj: object) -> object:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"cannot serialise {type(obj).__name__}")
