"""The map predictor at run time: observed low-res map in, occupancy probabilities on the same map out (no torch).

One prediction (docs/design.md §5): the 0.20 m observed map is cut to the north-up ego window around the robot's cell
(:func:`~edge_explorer.mapping.ego.pad_shift`), encoded as in training
(:func:`~edge_explorer.predict.encoding.encode_windows`), run through an exported model on whichever backend the
chain loaded it on (:func:`~edge_explorer.backends.chain.load_model`: Edge TPU → LiteRT CPU → onnxruntime CPU, each
artifact checked against its model card first), decoded (:func:`~edge_explorer.predict.encoding.decode_probabilities`)
and put back on the map (:func:`~edge_explorer.mapping.ego.unshift`; cells the window does not cover are NaN,
which thresholding reads as UNKNOWN).

The window size comes from the model: its one input must be ``[1, 2, S, S]`` (NCHW, as exported to ONNX) or
``[1, S, S, 2]`` (NHWC, as onnx2tf converts it to TFLite; batch may be dynamic) and its one output hold ``S × S``
probabilities. The layout is read from the declared input shape and the encoded window is transposed to it here,
so the TFLite graph needs no transpose op of its own (Edge TPU and XNNPACK run it end to end); an NHWC output is
moved back to channels-first before decoding. A :class:`PredictorRuntime` is also the ``window → probabilities``
callable the simulator and the benchmark take (:data:`edge_explorer.sim.env.Predictor`), so an exported model can be
flown in the training simulator unchanged.

Its :attr:`PredictorRuntime.thresholds` are those every reader thresholds this model's output with (the daemon, the
simulator, the benchmark): the card's calibrated ``thresholds`` when it has them (docs/design.md §5: they win;
written by ``edge-explorer train calibrate-predictor``), the defaults of :class:`~edge_explorer.predict.thresholding.
ThresholdConfig` otherwise, with the footprint the model learned on from the card's ``envelope_m``: absent for a
model trained on the 21 × 11 m plans (the default envelope: beyond it nothing is predicted OCCUPIED,
:mod:`~edge_explorer.predict.thresholding`), ``null`` for one that also learned whole floors (no envelope; written by
``train ship-predictor --whole-floors``).

Calibrated probabilities (issue #56): when the card has a ``calibration`` entry (a strictly increasing map fitted on
val, :mod:`edge_explorer.predict.probability_calibration`, written by ``edge-explorer train
calibrate-probabilities``), every output goes through it, so every reader gets a P(occupied) that means what it
says; :attr:`PredictorRuntime.thresholds` then carries the same map, so thresholding cuts the calibrated
probabilities exactly where it cut the raw ones (the card's ``thresholds`` stay in raw units). :meth:`PredictorRuntime.
raw` and :meth:`PredictorRuntime.uncalibrated` give the model's own output, for measuring and fitting the map.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np

from edge_explorer.backends.card import CARD_FILE, CardError
from edge_explorer.backends.chain import LoadedModel
from edge_explorer.errors import EdgeExplorerError
from edge_explorer.mapping.ego import Cell, pad_shift, unshift
from edge_explorer.predict.encoding import INPUT_CHANNELS, decode_probabilities, encode_windows
from edge_explorer.predict.probability_calibration import CALIBRATION_KEY, ProbabilityCalibration
from edge_explorer.predict.thresholding import ENVELOPE_M, ThresholdConfig, beyond_envelope

THRESHOLDS_KEY = "thresholds"  # the card's calibrated {"t_f_max", "t_o", ...}
ENVELOPE_KEY = "envelope_m"  # the card's training footprint [long, short] in metres; null: whole floors, no envelope
BEYOND_KEY = "beyond_envelope"  # the card's whole-floor model: the name of a model folder beside this one's


class PredictorModelError(EdgeExplorerError):
    """The loaded model does not have the predictor's input and output layout."""


def _card_doc(card: Path, what: str) -> tuple[Path, dict]:
    """(the card's path, its JSON object) for ``card.json`` or its folder; :class:`CardError` naming ``what`` was
    being read when the card is unreadable."""
    if card.is_dir():
        card = card / CARD_FILE
    try:
        doc = json.loads(card.read_text())
        if not isinstance(doc, dict):
            raise ValueError("not a JSON object")
    except (OSError, ValueError) as exc:
        raise CardError(f"{card}: cannot read the predictor's {what} ({exc})") from exc
    return card, doc


def card_thresholds(card: Path) -> ThresholdConfig:
    """The thresholds of a predictor's card (``card.json`` or its folder): its calibrated ``thresholds`` when it has
    them, the defaults otherwise. Raises :class:`CardError` if the card is unreadable or its values are invalid."""
    card, doc = _card_doc(card, "thresholds")
    entry = doc.get(THRESHOLDS_KEY)
    envelope = card_envelope_m(doc, card)
    if entry is None:
        return ThresholdConfig(envelope_m=envelope)
    try:
        return ThresholdConfig(t_f_max=float(entry["t_f_max"]), t_o=float(entry["t_o"]), envelope_m=envelope)
    except (TypeError, KeyError, ValueError) as exc:
        raise CardError(f"{card}: '{THRESHOLDS_KEY}' needs numbers t_f_max <= t_o in [0, 1] ({exc!r})") from exc


def card_envelope_m(doc: dict, card: Path) -> tuple[float, float]:
    """The footprint (long, short) in metres the card's model learned on: the default envelope when the card does
    not say, (inf, inf) for ``null`` (a model that learned whole floors). Raises :class:`CardError` otherwise."""
    if ENVELOPE_KEY not in doc:
        return ENVELOPE_M
    value = doc[ENVELOPE_KEY]
    if value is None:
        return (math.inf, math.inf)
    try:
        long_m, short_m = (float(v) for v in value)
    except (TypeError, ValueError) as exc:
        raise CardError(f"{card}: '{ENVELOPE_KEY}' must be [long, short] in metres or null ({exc!r})") from exc
    if not long_m >= short_m > 0:
        raise CardError(f"{card}: '{ENVELOPE_KEY}' must be [long, short] with long ≥ short > 0, got {value}")
    return (long_m, short_m)


def card_calibration(card: Path) -> ProbabilityCalibration | None:
    """The probability calibration map of a predictor's card (``card.json`` or its folder), None without one. Raises
    :class:`CardError` if the card is unreadable or the entry is invalid."""
    card, doc = _card_doc(card, "calibration")
    entry = doc.get(CALIBRATION_KEY)
    if entry is None:
        return None
    try:
        return ProbabilityCalibration.from_json(entry)
    except (TypeError, KeyError, ValueError) as exc:
        raise CardError(f"{card}: bad '{CALIBRATION_KEY}' entry ({exc!r})") from exc


def card_beyond(card: Path) -> Path | None:
    """The card of the model that predicts beyond the envelope of the card's model (``card.json`` or its folder): its
    ``beyond_envelope`` folder beside this one's, None without the key. Raises :class:`CardError` when the key does
    not name a folder with a card."""
    card, doc = _card_doc(card, "whole-floor model")
    name = doc.get(BEYOND_KEY)
    if name is None:
        return None
    beyond = card.parent.parent / str(name) / CARD_FILE
    if not isinstance(name, str) or "/" in name or not beyond.is_file():
        raise CardError(f"{card}: '{BEYOND_KEY}' must name a model folder beside this one with a card, got {name!r}")
    return beyond


class PredictorRuntime:
    """An exported map predictor ready to run, with its thresholds (see the module docstring)."""

    def __init__(
        self,
        model: LoadedModel,
        thresholds: ThresholdConfig | None = None,
        calibrated: bool = True,
        beyond: PredictorRuntime | None = None,
    ) -> None:
        """``thresholds``: None reads them from the card beside the loaded artifact (:func:`card_thresholds`) with,
        if ``calibrated``, the card's probability calibration (:func:`card_calibration`); a config given is used as
        it is, its ``calibration`` (None: raw output) included. The runtime applies the map its thresholds carry.
        ``beyond``: a model that learned whole floors, which predicts instead of this one once the observed map spans
        more than this one's envelope (:meth:`for_map`); the thresholds then carry its own as ``beyond``."""
        inputs, outputs = model.backend.inputs, model.backend.outputs
        if len(inputs) != 1 or len(outputs) != 1:
            raise PredictorModelError(
                f"{model.name}: a predictor has one input and one output, this model has "
                f"{[s.name for s in inputs]} → {[s.name for s in outputs]}"
            )
        shape = inputs[0].shape
        nchw = len(shape) == 4 and shape[1] == INPUT_CHANNELS and shape[2] == shape[3] >= 1
        nhwc = len(shape) == 4 and shape[3] == INPUT_CHANNELS and shape[1] == shape[2] >= 1
        if not (nchw or nhwc) or shape[0] not in (1, -1):
            raise PredictorModelError(
                f"{model.name}: predictor input {inputs[0].name!r} must be [1, {INPUT_CHANNELS}, S, S] or "
                f"[1, S, S, {INPUT_CHANNELS}] (encoding.encode_windows), got {list(shape)}"
            )
        self.channels_last = not nchw
        self.window_cells = int(shape[2])
        out_size = math.prod(d for d in outputs[0].shape if d != -1)
        if out_size != self.window_cells**2:
            raise PredictorModelError(
                f"{model.name}: output {outputs[0].name!r} {list(outputs[0].shape)} is not one "
                f"{self.window_cells}×{self.window_cells} probability map"
            )
        self.model = model
        if thresholds is None:
            folder = model.artifact.parent
            calibration = card_calibration(folder) if calibrated else None
            thresholds = dataclasses.replace(card_thresholds(folder), calibration=calibration)
        if beyond is not None:
            if beyond.window_cells != self.window_cells or beyond.beyond is not None:
                raise PredictorModelError(
                    f"{beyond.model.name}: the whole-floor model must take this one's {self.window_cells}-cell window "
                    "and have no whole-floor model of its own"
                )
            thresholds = dataclasses.replace(thresholds, beyond=beyond.thresholds)
        self.beyond = beyond
        self.thresholds = thresholds
        self.calibration = thresholds.calibration
        self._input_name = inputs[0].name
        self._output_name = outputs[0].name

    def for_map(self, observed_codes: np.ndarray) -> PredictorRuntime:
        """The model that predicts on this observed 0.20 m map (or window): :attr:`beyond` once its observed cells
        span more than the envelope (the rule thresholding applies, :func:`~edge_explorer.predict.thresholding.
        beyond_envelope`), this one otherwise. A building that fits the envelope never reaches ``beyond``."""
        if self.beyond is not None and beyond_envelope(observed_codes, self.thresholds):
            return self.beyond
        return self

    def __call__(self, window: np.ndarray) -> np.ndarray:
        """float32 (S, S) occupancy probabilities of one int8 north-up ego window (S, S), calibrated if the card
        says how; by :attr:`beyond` when the window's own observed cells span more than the envelope (:meth:`predict`
        decides on the whole map)."""
        return self.for_map(window)._probabilities(window)

    def _probabilities(self, window: np.ndarray) -> np.ndarray:
        """This model's calibrated output."""
        probabilities = self.raw(window)
        return probabilities if self.calibration is None else self.calibration(probabilities)

    def uncalibrated(self) -> PredictorRuntime:
        """The same loaded model without the probability calibration (its raw output, raw thresholds)."""
        return PredictorRuntime(self.model, dataclasses.replace(self.thresholds, calibration=None))

    def raw(self, window: np.ndarray) -> np.ndarray:
        """float32 (S, S) probabilities as the model outputs them (no calibration map)."""
        if window.shape != (self.window_cells, self.window_cells):
            raise ValueError(f"window shape {window.shape}, the model takes {self.window_cells}×{self.window_cells}")
        batch = encode_windows(window)[np.newaxis]
        if self.channels_last:
            batch = np.ascontiguousarray(batch.transpose(0, 2, 3, 1))
        out = self.model.run({self._input_name: batch})[self._output_name]
        return decode_probabilities(np.moveaxis(out, -1, 1) if self.channels_last and out.ndim == 4 else out)

    def predict(self, low_codes: np.ndarray, robot_cell: Cell) -> np.ndarray:
        """float32 probabilities on the grid of ``low_codes`` (0.20 m observed map), NaN outside the window; by
        :attr:`beyond` once the map's observed cells span more than the envelope (:meth:`for_map`)."""
        window = pad_shift(low_codes, robot_cell, self.window_cells)
        probabilities = self.for_map(low_codes)._probabilities(window)
        return unshift(probabilities, robot_cell, low_codes.shape, fill=np.float32(np.nan))


def thresholds_of(predictor: object) -> ThresholdConfig:
    """The thresholds for ``predictor``'s output: a :class:`PredictorRuntime`'s own (its card's), the defaults for any
    other predictor (torch weights, test doubles)."""
    return predictor.thresholds if isinstance(predictor, PredictorRuntime) else ThresholdConfig()
