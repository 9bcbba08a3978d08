"""Model cards: the ``card.json`` beside each model's artifacts, checked before any artifact is loaded.

Schema (version 1). Keys other than these (metrics, provenance, accuracy gates…) are the exporter's and are kept
but not checked here::

    {
      "model": "predictor",                       # optional; defaults to the card's folder name
      "artifacts": {                              # file name (relative to the card's folder) → description
        "predictor_int8.tflite": {
          "sha256": "<64 hex digits of the file>",
          "format": "onnx" | "tflite" | "edgetpu_tflite",
          "precision": "fp32" | "fp16" | "int8",   # optional, default "fp32"
          "inputs":  [{"name": "map", "shape": [1, 1, 256, 256], "dtype": "int8"}],
          "outputs": [{"name": "prob", "shape": [1, 1, 256, 256], "dtype": "int8"}]
        }
      }
    }

``shape`` uses −1 for a dynamic dimension. ``dtype`` is the numpy name of the tensor as stored in the artifact
(``int8`` for quantized I/O; the backends still exchange float32 with callers). The backend chain checks the
SHA-256 before loading and the names, shapes and dtypes after.
"""

from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from edge_explorer.backends.base import TensorSpec
from edge_explorer.errors import EdgeExplorerError

CARD_FILE = "card.json"
ARTIFACT_FORMATS = ("onnx", "tflite", "edgetpu_tflite")
PRECISIONS = ("fp32", "fp16", "int8")


class CardError(EdgeExplorerError):
    """A model card is missing, malformed, or disagrees with its artifact."""


@dataclass(frozen=True)
class TensorCard:
    name: str
    shape: tuple[int, ...]
    dtype: str

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "shape": list(self.shape), "dtype": self.dtype}


@dataclass(frozen=True)
class ArtifactCard:
    file: str
    sha256: str
    format: str
    inputs: tuple[TensorCard, ...]
    outputs: tuple[TensorCard, ...]
    precision: str = "fp32"

    @classmethod
    def describe(
        cls,
        path: Path,
        artifact_format: str,
        inputs: Sequence[TensorSpec],
        outputs: Sequence[TensorSpec],
        precision: str = "fp32",
    ) -> ArtifactCard:
        """The card entry for an artifact on disk (what an exporter writes): hashes the file."""
        return cls(
            path.name,
            sha256_of(path),
            artifact_format,
            tuple(TensorCard(s.name, s.shape, s.dtype) for s in inputs),
            tuple(TensorCard(s.name, s.shape, s.dtype) for s in outputs),
            precision,
        )

    def to_json(self) -> dict[str, Any]:
        return {
            "sha256": self.sha256,
            "format": self.format,
            "precision": self.precision,
            "inputs": [t.to_json() for t in self.inputs],
            "outputs": [t.to_json() for t in self.outputs],
        }


@dataclass(frozen=True)
class ModelCard:
    path: Path
    model: str
    artifacts: Mapping[str, ArtifactCard]

    def artifact_path(self, artifact: ArtifactCard) -> Path:
        return self.path.parent / artifact.file


def sha256_of(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def write_card(
    path: Path, model: str, artifacts: Sequence[ArtifactCard], extra: Mapping[str, Any] | None = None
) -> None:
    """Write ``card.json`` (``extra``: the exporter's other keys, written first)."""
    doc = {**(extra or {}), "model": model, "artifacts": {a.file: a.to_json() for a in artifacts}}
    path.write_text(json.dumps(doc, indent=2) + "\n")


def load_card(path: Path) -> ModelCard:
    """Read and validate a card (a ``card.json`` path or the folder holding one)."""
    if path.is_dir():
        path = path / CARD_FILE
    try:
        doc = json.loads(path.read_text())
    except OSError as exc:
        raise CardError(f"{path}: cannot read the model card ({exc.strerror or exc})") from exc
    except json.JSONDecodeError as exc:
        raise CardError(f"{path}: the model card is not valid JSON ({exc})") from exc
    if not isinstance(doc, dict) or not isinstance(doc.get("artifacts"), dict) or not doc["artifacts"]:
        raise CardError(f"{path}: a model card needs a non-empty 'artifacts' object")
    model = doc.get("model", path.parent.name)
    artifacts = {name: _artifact(path, name, entry) for name, entry in doc["artifacts"].items()}
    return ModelCard(path, str(model), artifacts)


def _artifact(card: Path, file: str, entry: Any) -> ArtifactCard:
    where = f"{card}: artifact {file!r}"
    if not isinstance(entry, dict):
        raise CardError(f"{where}: expected an object")
    if Path(file).name != file:
        raise CardError(f"{where}: artifact names are file names in the card's folder, not paths")
    sha = entry.get("sha256")
    if not isinstance(sha, str) or not re.fullmatch(r"[0-9a-f]{64}", sha):
        raise CardError(f"{where}: 'sha256' must be 64 lowercase hex digits")
    fmt = entry.get("format")
    if fmt not in ARTIFACT_FORMATS:
        raise CardError(f"{where}: 'format' must be one of {', '.join(ARTIFACT_FORMATS)}, got {fmt!r}")
    precision = entry.get("precision", "fp32")
    if precision not in PRECISIONS:
        raise CardError(f"{where}: 'precision' must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    return ArtifactCard(file, sha, fmt, _tensors(where, entry, "inputs"), _tensors(where, entry, "outputs"), precision)


def _tensors(where: str, entry: dict, key: str) -> tuple[TensorCard, ...]:
    items = entry.get(key)
    if not isinstance(items, list) or not items:
        raise CardError(f"{where}: '{key}' must be a non-empty list of {{name, shape, dtype}}")
    out = []
    for item in items:
        ok = (
            isinstance(item, dict)
            and isinstance(item.get("name"), str)
            and isinstance(item.get("dtype"), str)
            and isinstance(item.get("shape"), list)
            and all(isinstance(d, int) and d >= -1 for d in item["shape"])
        )
        if not ok:
            raise CardError(f"{where}: bad entry in '{key}': {item!r} (expected name, shape of ints ≥ −1, dtype)")
        out.append(TensorCard(item["name"], tuple(item["shape"]), item["dtype"]))
    return tuple(out)


def verify_sha256(card: ModelCard, artifact: ArtifactCard) -> None:
    """Raise :class:`CardError` unless the artifact file exists and hashes to the card's SHA-256."""
    path = card.artifact_path(artifact)
    if not path.is_file():
        raise CardError(f"{artifact.file}: missing (the card {card.path} lists it)")
    actual = sha256_of(path)
    if actual != artifact.sha256:
        raise CardError(
            f"{artifact.file}: sha256 mismatch (card {artifact.sha256[:12]}…, file {actual[:12]}…): "
            "the file is corrupted or is not the artifact the card describes"
        )


def verify_tensors(artifact: ArtifactCard, inputs: Sequence[TensorSpec], outputs: Sequence[TensorSpec]) -> None:
    """Raise :class:`CardError` unless the loaded model's tensors match the card's names, shapes and dtypes."""
    for kind, card_tensors, model_tensors in (
        ("input", artifact.inputs, inputs),
        ("output", artifact.outputs, outputs),
    ):
        by_name = {t.name: t for t in model_tensors}
        card_names = sorted(t.name for t in card_tensors)
        if sorted(by_name) != card_names:
            raise CardError(f"{artifact.file}: {kind}s {sorted(by_name)} differ from the card's {card_names}")
        for expected in card_tensors:
            actual = by_name[expected.name]
            shapes_match = len(expected.shape) == len(actual.shape) and all(
                a == b or -1 in (a, b) for a, b in zip(expected.shape, actual.shape, strict=True)
            )
            if not shapes_match or expected.dtype != actual.dtype:
                raise CardError(
                    f"{artifact.file}: {kind} {expected.name!r} is {list(actual.shape)} {actual.dtype}, "
                    f"the card says {list(expected.shape)} {expected.dtype}"
                )
