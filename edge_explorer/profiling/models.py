"""The shipped models on their own: graph size (MACs, parameters), every artifact on every backend, Edge TPU notes.

For each model folder (``models/<name>/card.json``) and each (backend, precision) pair the card offers, the model
is loaded through the same backend chain the daemon uses (:func:`~edge_explorer.backends.chain.load_model`, with
its SHA-256 and tensor checks) and run ``repeats`` times after ``warmup`` runs on fixed pseudo-random inputs of the
model's own shapes (dense networks take the same time whatever the values). A backend that cannot run here (no
Edge TPU on this host) is listed with its reason, not measured.

MACs and parameters come from the card when the exporter wrote them (``macs``, ``params``), else they are counted
from the fp32 ONNX graph with onnx-tool (the ``dev`` extra); with neither, they are reported as unknown. The Edge
TPU compatibility summary is whatever the export step wrote into the card under a key naming the Edge TPU.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from edge_explorer.backends.card import CARD_FILE, load_card
from edge_explorer.backends.chain import BACKENDS, load_model
from edge_explorer.errors import EdgeExplorerError

MODEL_NAMES: tuple[str, ...] = ("predictor", "policy")


@dataclass(frozen=True)
class GraphSize:
    """Multiply-accumulates per inference and parameter count; ``source`` says where they come from."""

    macs: float | None
    params: float | None
    source: str


@dataclass(frozen=True)
class BackendRun:
    """One artifact on one backend: its latency samples, or why it was not measured."""

    model: str
    backend: str
    precision: str
    artifact: str | None  # the file the chain loaded
    samples_ms: np.ndarray | None  # None when not measured
    note: str  # the chain's report line, or the reason it could not run here


@dataclass(frozen=True)
class ModelInfo:
    """One model folder: present or not, its size, its runs, the exporter's Edge TPU summary."""

    name: str
    card: Path
    present: bool
    note: str  # why it is missing or unusable; "" when fine
    size: GraphSize
    runs: tuple[BackendRun, ...]
    edgetpu: Any  # the card's Edge TPU entry (dict or text), None when the card has none


def graph_size(card_path: Path) -> GraphSize:
    """MACs and parameters of the model behind ``card_path`` (see the module docstring for the sources)."""
    doc = json.loads(card_path.read_text())
    macs, params = _find_number(doc, "macs"), _find_number(doc, "params")
    if macs is not None and params is not None:
        return GraphSize(macs, params, "model card")
    card = load_card(card_path)
    onnx_files = sorted(
        (a for a in card.artifacts.values() if a.format == "onnx"), key=lambda a: (a.precision != "fp32", a.file)
    )
    if not onnx_files:
        return GraphSize(macs, params, "unknown: no MACs in the card and no ONNX artifact to count them from")
    path = card.artifact_path(onnx_files[0])
    try:
        counted_macs, counted_params = count_onnx(path)
    except ImportError:
        return GraphSize(macs, params, "unknown: install the dev extra (onnx-tool) to count MACs from the graph")
    return GraphSize(
        macs if macs is not None else counted_macs,
        params if params is not None else counted_params,
        f"counted by onnx-tool from {path.name}",
    )


def count_onnx(path: Path) -> tuple[float, float]:
    """(MACs, parameters) of one inference of an ONNX graph, by onnx-tool's shape inference and node profiles."""
    import onnx_tool

    model = onnx_tool.Model(str(path), {"verbose": False})
    graph = model.graph
    graph.graph_reorder_nodes()
    graph.shape_infer()
    graph.profile()
    macs = graph.macs[0] if isinstance(graph.macs, (list, tuple)) else graph.macs
    return float(macs), float(graph.params)


def _find_number(doc: Any, key: str) -> float | None:
    """The first numeric value under ``key`` anywhere in a card (top level first)."""
    if isinstance(doc, dict):
        value = doc.get(key)
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        for child in doc.values():
            found = _find_number(child, key)
            if found is not None:
                return found
    return None


def edgetpu_summary(card_path: Path) -> Any:
    """The exporter's Edge TPU compatibility entry: the shallowest card value whose key names the Edge TPU (the
    exporter may nest it under its TFLite format), outside ``artifacts``."""
    level = [json.loads(card_path.read_text())]
    while level:
        children = []
        for table in level:
            for key, value in table.items():
                if key == "artifacts":
                    continue
                if "edgetpu" in key.lower().replace("_", "").replace("-", ""):
                    return value
                if isinstance(value, dict):
                    children.append(value)
        level = children
    return None


def feed_for(specs: tuple[Any, ...], seed: int = 0) -> dict[str, np.ndarray]:
    """Fixed pseudo-random float32 inputs in [−1, 1] of each input's shape (dynamic dimensions set to 1); the
    backend quantizes them where its input is integer."""
    rng = np.random.default_rng(seed)
    return {
        s.name: rng.uniform(-1.0, 1.0, tuple(1 if d == -1 else d for d in s.shape)).astype(np.float32) for s in specs
    }


def time_calls(call: Callable[[], object], repeats: int, warmup: int) -> np.ndarray:
    """Wall-clock milliseconds of ``repeats`` calls after ``warmup`` untimed ones."""
    for _ in range(warmup):
        call()
    out = np.empty(repeats)
    for i in range(repeats):
        start = time.perf_counter()
        call()
        out[i] = 1e3 * (time.perf_counter() - start)
    return out


def bench_models(
    models_dir: Path,
    backends: tuple[str, ...],
    repeats: int,
    warmup: int,
    num_threads: int = 1,
    on_run: Callable[[str], None] = lambda label: None,
) -> list[ModelInfo]:
    """Every model folder of :data:`MODEL_NAMES` under ``models_dir``, each artifact on each of ``backends``."""
    unknown = [b for b in backends if b not in BACKENDS]
    if unknown:
        raise EdgeExplorerError(f"unknown backend(s) {unknown}: choose from {', '.join(BACKENDS)}")
    infos = []
    for name in MODEL_NAMES:
        card_path = models_dir / name / CARD_FILE
        if not card_path.is_file():
            infos.append(
                ModelInfo(name, card_path, False, f"{card_path} is missing", GraphSize(None, None, "–"), (), None)
            )
            continue
        try:
            card = load_card(card_path)
            size = graph_size(card_path)
            edgetpu = edgetpu_summary(card_path)
        except (EdgeExplorerError, json.JSONDecodeError) as exc:
            infos.append(ModelInfo(name, card_path, False, str(exc), GraphSize(None, None, "–"), (), None))
            continue
        pairs = sorted({(b, a.precision) for a in card.artifacts.values() for b in backends if _runs(b, a.format)})
        runs = [
            BackendRun(name, b, "–", None, None, f"no {BACKENDS[b].artifact_format} artifact in the card")
            for b in backends
            if b not in {pair[0] for pair in pairs}
        ]
        for backend, precision in pairs:
            on_run(f"{name} {precision} on {backend}")
            runs.append(_bench_one(card_path, name, backend, precision, repeats, warmup, num_threads))
        infos.append(ModelInfo(name, card_path, True, "", size, tuple(runs), edgetpu))
    return infos


def _runs(backend: str, artifact_format: str) -> bool:
    return BACKENDS[backend].artifact_format == artifact_format


def _bench_one(
    card_path: Path, name: str, backend: str, precision: str, repeats: int, warmup: int, num_threads: int
) -> BackendRun:
    try:
        model = load_model(card_path, (backend,), precision, num_threads)
    except EdgeExplorerError as exc:
        return BackendRun(name, backend, precision, None, None, str(exc))
    feed = feed_for(model.backend.inputs)
    samples = time_calls(lambda: model.run(feed), repeats, warmup)
    return BackendRun(name, backend, precision, model.artifact.name, samples, model.report)
