"""Quantization recipes: one TOML per model in ``quantize/``, validated here with one-line errors.

A recipe says what to export and how to judge it::

    model = "predictor"                     # predictor | policy: the network, its calibration, gates
    checkpoint = "models/predictor/predictor.safetensors"   # relative to the recipe's folder's parent (the repo)
    folder = "predictor"                    # optional: the model folder under --out (default: the model's name),
                                            # e.g. predictor_floors for the whole-floor predictor

    [calibration]                           # observations recorded from simulator rollouts on the val split
    split = "val"
    plans = 16                              # val plans flown for calibration …
    held_back_plans = 8                     # … and further val plans, never calibrated on, for the accuracy gates
    per_plan = 8                            # observations (policy: goal decisions) recorded per plan
    explorer = "random-goal"                # predictor: random-goal | frontier | fuel; policy: policy | random
    seed = 0
    predictor = "models/predictor"          # policy only, optional: the thres map's predictor (a model
                                            # folder or a .safetensors U-Net, as bench explore --predictor)

    [quantization]
    method = "minmax"                       # minmax | entropy | percentile (onnxruntime's calibrators)
    per_channel = true
    percentile = 99.999                     # percentile only
    onnx_float_output_conv = false          # int8 ONNX only: leave the graph's last Conv in float (TFLite stays
                                            # full-integer for the Edge TPU)

    [formats]
    produce = ["onnx_fp32", "onnx_int8", "tflite_int8"]

    [gates]                                 # predictor: max_f1_drop, min_cell_agreement;
                                            # policy: min_top1_agreement (masked argmax)

    [latency]
    repeats = 30                            # timed runs per format (after warm-up), one thread

Paths are resolved against the project root (the recipe folder's parent), so ``quantize/predictor.toml`` works from
anywhere. Every key is checked: an unknown key or value names itself and the allowed choices. The gates see
``held_back_plans × per_plan`` held-back observations (fewer only where an episode has nothing left to explore).
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from edge_explorer.errors import EdgeExplorerError

MODELS = ("predictor", "policy")
METHODS = ("minmax", "entropy", "percentile")
FORMATS = ("onnx_fp32", "onnx_int8", "tflite_int8")
EXPLORERS = {
    "predictor": ("random-goal", "frontier", "fuel"),
    "policy": ("policy", "random"),
}
GATE_KEYS = {
    "predictor": ("max_f1_drop", "min_cell_agreement"),
    "policy": ("min_top1_agreement",),
}


class RecipeError(EdgeExplorerError):
    """A quantization recipe is missing, malformed or asks for something that does not exist."""


@dataclass(frozen=True)
class CalibrationConfig:
    """Where the calibration and held-back observations come from (simulator rollouts on ``split``)."""

    split: str = "val"
    plans: int = 16
    held_back_plans: int = 8
    per_plan: int = 8
    explorer: str = "random-goal"
    seed: int = 0
    predictor: Path | None = None


@dataclass(frozen=True)
class QuantizationConfig:
    method: str = "minmax"
    per_channel: bool = True
    percentile: float = 99.999
    onnx_float_output_conv: bool = False


@dataclass(frozen=True)
class Recipe:
    """A validated recipe; ``path`` is the TOML it came from."""

    path: Path
    model: str
    checkpoint: Path
    calibration: CalibrationConfig
    quantization: QuantizationConfig
    formats: tuple[str, ...]
    gates: Mapping[str, float] = field(default_factory=dict)
    latency_repeats: int = 30
    folder: str = ""  # the model folder under ``--out``; "" = the model's name

    @property
    def name(self) -> str:
        """The artifacts' file prefix: the model (``predictor_int8.tflite``)."""
        return self.model

    @property
    def out_folder(self) -> str:
        """The model folder under ``--out`` (``models/<out_folder>/``)."""
        return self.folder or self.model


def _table(doc: Mapping[str, Any], key: str, where: Path) -> dict[str, Any]:
    value = doc.get(key, {})
    if not isinstance(value, dict):
        raise RecipeError(f"{where}: [{key}] must be a table")
    return value


def _check_keys(where: str, table: Mapping[str, Any], allowed: tuple[str, ...]) -> None:
    unknown = sorted(set(table) - set(allowed))
    if unknown:
        raise RecipeError(f"{where}: unknown key(s) {', '.join(unknown)}; allowed: {', '.join(allowed)}")


def _typed(where: str, key: str, value: Any, kind: type | tuple[type, ...]) -> Any:
    if isinstance(value, bool) and kind is not bool or not isinstance(value, kind):
        name = kind.__name__ if isinstance(kind, type) else " or ".join(k.__name__ for k in kind)
        raise RecipeError(f"{where}: '{key}' must be a {name}, got {value!r}")
    return value


def _positive(where: str, key: str, value: Any) -> int:
    if _typed(where, key, value, int) < 1:
        raise RecipeError(f"{where}: '{key}' must be ≥ 1, got {value}")
    return value


def load_recipe(path: str | Path) -> Recipe:
    """Read and validate a recipe; :class:`RecipeError` (one line) on anything wrong."""
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text())
    except OSError as exc:
        raise RecipeError(f"{path}: cannot read the recipe ({exc.strerror or exc}); see quantize/*.toml") from exc
    except tomllib.TOMLDecodeError as exc:
        raise RecipeError(f"{path}: not valid TOML ({exc})") from exc
    root = path.resolve().parent.parent
    where = str(path)
    keys = ("model", "checkpoint", "folder", "calibration", "quantization", "formats", "gates", "latency")
    _check_keys(where, doc, keys)
    model = doc.get("model")
    if model not in MODELS:
        raise RecipeError(f"{where}: 'model' must be one of {', '.join(MODELS)}, got {model!r}")
    folder = _typed(where, "folder", doc.get("folder", model), str)
    if not folder or "/" in folder or folder.startswith("."):
        raise RecipeError(f"{where}: 'folder' must be a plain folder name under --out, got {folder!r}")
    checkpoint = root / _typed(where, "checkpoint", doc.get("checkpoint"), str)

    cal = _table(doc, "calibration", path)
    _check_keys(f"{where} [calibration]", cal, tuple(CalibrationConfig.__dataclass_fields__))
    cw = f"{where} [calibration]"
    explorer = cal.get("explorer", EXPLORERS[model][0])
    if explorer not in EXPLORERS[model]:
        choices = ", ".join(EXPLORERS[model])
        raise RecipeError(f"{cw}: 'explorer' for a {model} must be one of {choices}, got {explorer!r}")
    if cal.get("split", "val") != "val":
        raise RecipeError(f"{cw}: 'split' must be 'val' (train or test data would leak), got {cal['split']!r}")
    predictor = cal.get("predictor")
    if predictor is not None and model == "predictor":
        raise RecipeError(f"{cw}: 'predictor' is for policy recipes (the thres map's predictor) only")
    calibration = CalibrationConfig(
        plans=_positive(cw, "plans", cal.get("plans", CalibrationConfig.plans)),
        held_back_plans=_positive(cw, "held_back_plans", cal.get("held_back_plans", CalibrationConfig.held_back_plans)),
        per_plan=_positive(cw, "per_plan", cal.get("per_plan", CalibrationConfig.per_plan)),
        explorer=explorer,
        seed=_typed(cw, "seed", cal.get("seed", 0), int),
        predictor=None if predictor is None else root / _typed(cw, "predictor", predictor, str),
    )

    q = _table(doc, "quantization", path)
    qw = f"{where} [quantization]"
    _check_keys(qw, q, tuple(QuantizationConfig.__dataclass_fields__))
    method = q.get("method", "minmax")
    if method not in METHODS:
        raise RecipeError(f"{qw}: unknown method {method!r}; choose one of {', '.join(METHODS)}")
    percentile = float(_typed(qw, "percentile", q.get("percentile", 99.999), (int, float)))
    if not 50.0 < percentile <= 100.0:
        raise RecipeError(f"{qw}: 'percentile' must be in (50, 100], got {percentile}")
    quantization = QuantizationConfig(
        method,
        _typed(qw, "per_channel", q.get("per_channel", True), bool),
        percentile,
        _typed(qw, "onnx_float_output_conv", q.get("onnx_float_output_conv", False), bool),
    )

    f = _table(doc, "formats", path)
    _check_keys(f"{where} [formats]", f, ("produce",))
    produce = f.get("produce", list(FORMATS))
    if not isinstance(produce, list) or not produce or any(x not in FORMATS for x in produce):
        choices = ", ".join(FORMATS)
        raise RecipeError(f"{where} [formats]: 'produce' must be a non-empty list of {choices}, got {produce!r}")
    if "onnx_fp32" not in produce:
        raise RecipeError(f"{where} [formats]: 'produce' must include onnx_fp32 (every other format is made from it)")

    g = _table(doc, "gates", path)
    gw = f"{where} [gates]"
    _check_keys(gw, g, GATE_KEYS[model])
    missing = [k for k in GATE_KEYS[model] if k not in g]
    if missing:
        raise RecipeError(f"{gw}: a {model} recipe needs the gate(s) {', '.join(missing)}")
    gates = {k: float(_typed(gw, k, v, (int, float))) for k, v in g.items()}
    if any(not 0.0 <= v <= 1.0 for v in gates.values()):
        raise RecipeError(f"{gw}: gate values are fractions in [0, 1], got {gates}")

    lat = _table(doc, "latency", path)
    _check_keys(f"{where} [latency]", lat, ("repeats",))
    repeats = _positive(f"{where} [latency]", "repeats", lat.get("repeats", 30))
    formats = tuple(dict.fromkeys(produce))
    return Recipe(path, model, checkpoint, calibration, quantization, formats, gates, repeats, folder)


def check_inputs_exist(recipe: Recipe) -> None:
    """The files the recipe names must exist before any work starts."""
    if not recipe.checkpoint.is_file():
        hint = "train it first (edge-explorer train …) or fix 'checkpoint'"
        raise RecipeError(f"{recipe.path}: checkpoint {recipe.checkpoint} does not exist; {hint}")
    predictor = recipe.calibration.predictor
    if predictor is not None and not predictor.exists():
        raise RecipeError(f"{recipe.path} [calibration]: predictor {predictor} does not exist")
