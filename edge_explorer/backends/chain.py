"""The backend fallback chain: load a model on the first backend, in a device profile's order, that can run it.

For each backend in order, the card's artifacts of that backend's format are tried (the preferred precision
first). An artifact is used only after its SHA-256 matches the card (before loading) and its tensors match the card
(after loading). One log line says which backend runs the model and why the others were skipped, e.g.::

    predictor: litert-cpu on predictor_int8.tflite (edgetpu skipped: no Edge TPU present: libedgetpu.so.1 could
    not be loaded; sha256 ok)

When nothing works, :class:`ModelLoadError` lists every reason (a corrupted file shows as a sha256 mismatch).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from edge_explorer.backends.base import BackendUnavailable, InferenceBackend
from edge_explorer.backends.card import (
    ArtifactCard,
    CardError,
    ModelCard,
    load_card,
    verify_sha256,
    verify_tensors,
)
from edge_explorer.backends.edgetpu import EdgeTpuBackend
from edge_explorer.backends.litert_cpu import LiteRtCpuBackend
from edge_explorer.backends.onnxruntime_cpu import OnnxRuntimeCpuBackend
from edge_explorer.errors import EdgeExplorerError

log = logging.getLogger(__name__)

BACKENDS: dict[str, type[InferenceBackend]] = {
    cls.name: cls for cls in (EdgeTpuBackend, LiteRtCpuBackend, OnnxRuntimeCpuBackend)
}
DEFAULT_BACKEND_ORDER: tuple[str, ...] = ("edgetpu", "litert-cpu", "onnxruntime-cpu")


class ModelLoadError(EdgeExplorerError):
    """No backend in the chain could load the model; the message lists why for each."""


@dataclass(frozen=True)
class LoadedModel:
    """A model ready to run, with where it runs and the report line that was logged."""

    name: str
    backend: InferenceBackend
    artifact: Path
    report: str

    def run(self, inputs: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        return self.backend.run(inputs)


def load_model(
    card_path: Path,
    backend_order: Sequence[str] = DEFAULT_BACKEND_ORDER,
    precision: str = "int8",
    num_threads: int = 1,
) -> LoadedModel:
    """Load the model described by ``card_path`` (a ``card.json`` or its folder) on the first working backend."""
    unknown = [name for name in backend_order if name not in BACKENDS]
    if unknown:
        raise ModelLoadError(f"unknown backend(s) {unknown}: choose from {', '.join(BACKENDS)}")
    card = load_card(card_path)
    reasons: list[str] = []
    for backend_name in backend_order:
        backend_cls = BACKENDS[backend_name]
        candidates = sorted(
            (a for a in card.artifacts.values() if a.format == backend_cls.artifact_format),
            key=lambda a: (a.precision != precision, a.file),
        )
        if not candidates:
            reasons.append(f"{backend_name} skipped: no {backend_cls.artifact_format} artifact in the card")
            continue
        for artifact in candidates:
            try:
                backend = _load_verified(card, artifact, backend_cls, num_threads)
            except BackendUnavailable as exc:
                reasons.append(f"{backend_name} skipped: {exc}")
                break  # the backend itself is missing: its other artifacts cannot fare better
            except CardError as exc:
                reasons.append(f"{backend_name} skipped: {exc}")
                continue
            skipped = "; ".join([*reasons, "sha256 ok"])
            report = f"{card.model}: {backend_name} on {artifact.file} ({skipped})"
            log.info(report)
            return LoadedModel(card.model, backend, card.artifact_path(artifact), report)
    raise ModelLoadError(f"{card.model}: no backend could load it ({'; '.join(reasons)})")


def _load_verified(
    card: ModelCard, artifact: ArtifactCard, backend_cls: type[InferenceBackend], num_threads: int
) -> InferenceBackend:
    """The artifact loaded on ``backend_cls`` after both card checks; CardError / BackendUnavailable otherwise."""
    verify_sha256(card, artifact)
    backend = backend_cls(num_threads)
    try:
        backend.load(card.artifact_path(artifact))
    except BackendUnavailable:
        raise
    except Exception as exc:  # noqa: BLE001 - a runtime's own load error, e.g. an op it lacks
        raise CardError(f"{artifact.file}: {backend_cls.name} could not load it ({exc})") from exc
    verify_tensors(artifact, backend.inputs, backend.outputs)
    return backend
