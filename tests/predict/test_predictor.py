"""The predictor runtime wrapper on a tiny ONNX model built here (edge_explorer.predict.predictor)."""

from __future__ import annotations

import ctypes
import json
import logging
import math
from pathlib import Path

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper

from edge_explorer.backends.base import TensorSpec
from edge_explorer.backends.card import ArtifactCard, CardError, write_card
from edge_explorer.backends.chain import ModelLoadError, load_model
from edge_explorer.mapping.ego import pad_shift
from edge_explorer.predict.predictor import (
    PredictorModelError,
    PredictorRuntime,
    card_beyond,
    card_calibration,
    card_thresholds,
    thresholds_of,
)
from edge_explorer.predict.probability_calibration import ProbabilityCalibration
from edge_explorer.predict.thresholding import ENVELOPE_M, ThresholdConfig, thresholded_map
from edge_explorer.world.grid import CELL_DTYPE, FREE, OCCUPIED, UNKNOWN

WINDOW = 16  # cells: a small stand-in for the 256×256 window; the wrapper takes the size from the model
ORDER = ("edgetpu", "litert-cpu", "onnxruntime-cpu")


def write_predictor_model(
    folder: Path,
    window: int = WINDOW,
    channels: int = 2,
    edgetpu: bool = False,
    gain: float = 10.0,
    bias: float = 5.0,
) -> Path:
    """A ``predictor`` model folder: P(occupied) = sigmoid(gain·occupied − bias) per cell, as ONNX with its card.

    ``edgetpu``: also list a ``*_edgetpu.tflite`` artifact (not a real one: no Edge TPU is present here anyway).
    Returns the card's path.
    """
    folder.mkdir(parents=True, exist_ok=True)
    shape = [1, channels, window, window]
    out_shape = [1, 1, window, window]
    graph = helper.make_graph(
        [
            helper.make_node("Slice", ["map", "starts", "ends", "axes"], ["occupied"]),
            helper.make_node("Mul", ["occupied", "ten"], ["scaled"]),
            helper.make_node("Sub", ["scaled", "five"], ["logits"]),
            helper.make_node("Sigmoid", ["logits"], ["prob"]),
        ],
        "tiny-predictor",
        [helper.make_tensor_value_info("map", TensorProto.FLOAT, shape)],
        [helper.make_tensor_value_info("prob", TensorProto.FLOAT, out_shape)],
        [
            helper.make_tensor("starts", TensorProto.INT64, [1], [channels - 1]),
            helper.make_tensor("ends", TensorProto.INT64, [1], [channels]),
            helper.make_tensor("axes", TensorProto.INT64, [1], [1]),
            helper.make_tensor("ten", TensorProto.FLOAT, [], [gain]),
            helper.make_tensor("five", TensorProto.FLOAT, [], [bias]),
        ],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)], ir_version=8)
    onnx.checker.check_model(model)
    path = folder / "predictor_fp32.onnx"
    onnx.save(model, path)
    specs = [TensorSpec("map", tuple(shape), "float32")], [TensorSpec("prob", tuple(out_shape), "float32")]
    artifacts = [ArtifactCard.describe(path, "onnx", *specs)]
    if edgetpu:
        fake = folder / "predictor_int8_edgetpu.tflite"
        fake.write_bytes(b"TFL3 not really compiled for the Edge TPU")
        artifacts.append(ArtifactCard.describe(fake, "edgetpu_tflite", *specs, precision="int8"))
    card = folder / "card.json"
    write_card(card, "predictor", artifacts)
    return card


def set_card_key(card: Path, key: str, value: object) -> None:
    """Set one top-level key of a card (the artifacts' checks still pass: only a key changes)."""
    doc = json.loads(card.read_text())
    doc[key] = value
    card.write_text(json.dumps(doc))


def add_thresholds(card: Path, entry: object) -> None:
    """Add a ``thresholds`` key to a card as ``edge-explorer train calibrate-predictor`` does (nothing else changes)."""
    set_card_key(card, "thresholds", entry)


def expected_probability(codes: np.ndarray) -> np.ndarray:
    return (1.0 / (1.0 + np.exp(-(10.0 * (codes == OCCUPIED) - 5.0)))).astype(np.float32)


def test_window_prediction_uses_the_shared_encoding(tmp_path):
    predictor = PredictorRuntime(load_model(write_predictor_model(tmp_path / "predictor"), ORDER))
    assert predictor.window_cells == WINDOW
    window = np.random.default_rng(0).choice([FREE, UNKNOWN, OCCUPIED], size=(WINDOW, WINDOW)).astype(CELL_DTYPE)
    np.testing.assert_allclose(predictor(window), expected_probability(window), atol=1e-6)


def test_prediction_goes_back_onto_the_map_around_the_robot(tmp_path):
    predictor = PredictorRuntime(load_model(write_predictor_model(tmp_path / "predictor"), ORDER))
    codes = np.full((40, 30), FREE, dtype=CELL_DTYPE)
    codes[:, 0] = OCCUPIED
    robot = (20, 5)
    probabilities = predictor.predict(codes, robot)
    assert probabilities.shape == codes.shape and probabilities.dtype == np.float32
    half = WINDOW // 2
    rows, cols = slice(robot[0] - half, robot[0] + half), slice(0, robot[1] + half)  # the window's part on the map
    np.testing.assert_allclose(probabilities[rows, cols], expected_probability(codes[rows, cols]), atol=1e-6)
    outside = np.ones(codes.shape, dtype=bool)
    outside[rows, cols] = False
    assert np.isnan(probabilities[outside]).all()  # no prediction beyond the window: thresholding reads UNKNOWN
    window = pad_shift(codes, robot, WINDOW)
    assert window[half, half] == codes[robot]


def test_no_edge_tpu_falls_back_to_the_cpu_and_says_why(tmp_path, caplog):
    try:
        ctypes.CDLL("libedgetpu.so.1")
        pytest.skip("an Edge TPU runtime is installed on this host")
    except OSError:
        pass
    card = write_predictor_model(tmp_path / "predictor", edgetpu=True)
    with caplog.at_level(logging.INFO, logger="edge_explorer.backends.chain"):
        predictor = PredictorRuntime(load_model(card, ORDER))
    assert predictor.model.backend.name == "onnxruntime-cpu"
    assert "edgetpu skipped: no Edge TPU present" in predictor.model.report
    assert predictor.model.report in caplog.text


def test_a_corrupted_artifact_is_refused_before_loading(tmp_path):
    card = write_predictor_model(tmp_path / "predictor")
    artifact = card.parent / "predictor_fp32.onnx"
    data = bytearray(artifact.read_bytes())
    data[-1] ^= 0xFF
    artifact.write_bytes(bytes(data))
    with pytest.raises(ModelLoadError, match="sha256 mismatch"):
        PredictorRuntime(load_model(card, ORDER))


def test_a_model_with_another_input_layout_is_refused(tmp_path):
    card = write_predictor_model(tmp_path / "predictor", channels=1)
    with pytest.raises(PredictorModelError, match=r"must be \[1, 2, S, S\]"):
        PredictorRuntime(load_model(card, ORDER))


def test_the_card_s_calibrated_thresholds_are_the_runtime_s_and_the_defaults_without_them(tmp_path):
    card = write_predictor_model(tmp_path / "predictor")
    assert PredictorRuntime(load_model(card, ORDER)).thresholds == ThresholdConfig()
    add_thresholds(card, {"t_f_max": 0.1, "t_o": 0.9, "precision_target": 0.95, "calibration": {"met_target": True}})
    predictor = PredictorRuntime(load_model(card, ORDER))  # the artifacts' checks still pass: only a key was added
    assert predictor.thresholds == ThresholdConfig(t_f_max=0.1, t_o=0.9) == card_thresholds(card.parent)
    assert thresholds_of(predictor) == ThresholdConfig(t_f_max=0.1, t_o=0.9)
    assert thresholds_of(expected_probability) == ThresholdConfig()  # any other predictor: the defaults
    assert PredictorRuntime(load_model(card, ORDER), ThresholdConfig()).thresholds == ThresholdConfig()


@pytest.mark.parametrize("entry", [{"t_f_max": 0.95, "t_o": 0.9}, {"t_o": 0.9}, [0.1, 0.9], {"t_f_max": "x", "t_o": 1}])
def test_bad_thresholds_in_the_card_are_refused(tmp_path, entry):
    card = write_predictor_model(tmp_path / "predictor")
    add_thresholds(card, entry)
    with pytest.raises(CardError, match="'thresholds' needs"):
        PredictorRuntime(load_model(card, ORDER))


def test_the_card_s_training_envelope_reaches_the_thresholds_and_null_lifts_it(tmp_path):
    card = write_predictor_model(tmp_path / "predictor")
    add_thresholds(card, {"t_f_max": 0.1, "t_o": 0.9})
    assert card_thresholds(card).envelope_m == ENVELOPE_M  # a card that does not say: the 21 × 11 m plans'
    for value, expected in (([40.0, 20.0], (40.0, 20.0)), (None, (math.inf, math.inf))):
        set_card_key(card, "envelope_m", value)
        predictor = PredictorRuntime(load_model(card, ORDER))
        assert predictor.thresholds == ThresholdConfig(t_f_max=0.1, t_o=0.9, envelope_m=expected)
    # a whole-floor model: a wall predicted beyond the envelope stays OCCUPIED
    observed = np.full((200, 200), UNKNOWN, dtype=CELL_DTYPE)
    observed[100, 10:190] = FREE  # a 36 m corridor observed
    probabilities = np.full(observed.shape, 0.99, dtype=np.float32)
    assert (thresholded_map(probabilities, observed, 100.0, predictor.thresholds) == OCCUPIED).sum() > 0
    assert (thresholded_map(probabilities, observed, 100.0, ThresholdConfig()) == OCCUPIED).sum() == 0


@pytest.mark.parametrize("value", ["whole", [10.0, 20.0], [1.0]])
def test_a_bad_training_envelope_in_the_card_is_refused(tmp_path, value):
    card = write_predictor_model(tmp_path / "predictor")
    set_card_key(card, "envelope_m", value)
    with pytest.raises(CardError, match="'envelope_m' must be"):
        PredictorRuntime(load_model(card, ORDER))


def test_the_whole_floor_model_the_card_names_predicts_once_the_observed_map_outspans_the_envelope(tmp_path):
    card = write_predictor_model(tmp_path / "models" / "predictor")
    floors = write_predictor_model(tmp_path / "models" / "predictor_floors", gain=20.0)
    add_thresholds(floors, {"t_f_max": 0.2, "t_o": 0.8})
    assert card_beyond(card) is None  # a card that names none
    set_card_key(card, "beyond_envelope", "predictor_floors")
    assert card_beyond(card.parent) == floors
    within = PredictorRuntime(load_model(card, ORDER))
    predictor = PredictorRuntime(load_model(card, ORDER), beyond=PredictorRuntime(load_model(floors, ORDER)))
    assert predictor.thresholds == ThresholdConfig(beyond=ThresholdConfig(t_f_max=0.2, t_o=0.8))
    small = np.full((60, 60), UNKNOWN, dtype=CELL_DTYPE)
    small[30, 5:55] = OCCUPIED  # a 10 m wall seen: within the envelope
    large = np.full((60, 200), UNKNOWN, dtype=CELL_DTYPE)
    large[30, 5:195] = OCCUPIED  # a 38 m wall seen: beyond it
    cell = (31, 30)
    assert predictor.for_map(small) is predictor and predictor.for_map(large) is predictor.beyond
    np.testing.assert_array_equal(predictor.predict(small, cell), within.predict(small, cell))
    on_large = predictor.predict(large, cell)
    np.testing.assert_array_equal(on_large, predictor.beyond.predict(large, cell))
    assert np.nanmax(on_large) > np.nanmax(within.predict(large, cell))  # the whole-floor model's own output


@pytest.mark.parametrize("name", ["missing", "../predictor_floors", 3])
def test_a_whole_floor_model_the_card_cannot_name_is_refused(tmp_path, name):
    card = write_predictor_model(tmp_path / "models" / "predictor")
    set_card_key(card, "beyond_envelope", name)
    with pytest.raises(CardError, match="'beyond_envelope' must name a model folder beside this one"):
        card_beyond(card)


def test_the_card_s_probability_calibration_is_applied_to_every_output_and_to_the_thresholds(tmp_path):
    card = write_predictor_model(tmp_path / "predictor")
    add_thresholds(card, {"t_f_max": 0.3, "t_o": 0.9})
    calibration = ProbabilityCalibration("beta", a=0.6, b=-1.2, c=0.87)
    doc = json.loads(card.read_text())
    doc["calibration"] = {**calibration.to_json(), "val": {"ece_raw": 0.1}}  # extra keys are the card's record
    card.write_text(json.dumps(doc))
    assert card_calibration(card) == calibration
    predictor = PredictorRuntime(load_model(card, ORDER))  # the artifacts' checks still pass: only a key was added
    window = np.random.default_rng(0).choice([FREE, UNKNOWN, OCCUPIED], size=(WINDOW, WINDOW)).astype(CELL_DTYPE)
    np.testing.assert_allclose(predictor(window), calibration(expected_probability(window)), atol=1e-6)
    np.testing.assert_allclose(predictor.raw(window), expected_probability(window), atol=1e-6)
    assert predictor.thresholds == ThresholdConfig(t_f_max=0.3, t_o=0.9, calibration=calibration)
    assert thresholds_of(predictor).calibration == calibration  # every reader thresholds with the map
    raw = predictor.uncalibrated()
    assert raw.calibration is None and raw.thresholds == ThresholdConfig(t_f_max=0.3, t_o=0.9)
    np.testing.assert_allclose(raw(window), expected_probability(window), atol=1e-6)
    assert PredictorRuntime(load_model(card, ORDER), calibrated=False).thresholds == raw.thresholds


@pytest.mark.parametrize("entry", [{"method": "isotonic", "params": {}}, {"method": "beta"}, [1, 2]])
def test_a_bad_calibration_in_the_card_is_refused(tmp_path, entry):
    card = write_predictor_model(tmp_path / "predictor")
    set_card_key(card, "calibration", entry)
    with pytest.raises(CardError, match="'calibration'"):
        PredictorRuntime(load_model(card, ORDER))
