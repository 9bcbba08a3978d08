"""The goal-policy runtime wrapper on a tiny ONNX model built here (edge_explorer.plan.policy)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper

from edge_explorer.backends.base import TensorSpec
from edge_explorer.backends.card import ArtifactCard, write_card
from edge_explorer.backends.chain import load_model
from edge_explorer.mapping.ego import NUM_ACTIONS, OBSERVATION_WINDOW_CELLS, observation_from_maps
from edge_explorer.plan.goal_grid import GOAL_GRID_CELLS
from edge_explorer.plan.policy import PolicyModelError, PolicyRuntime
from edge_explorer.vehicle.dynamics import Action
from edge_explorer.world.grid import CELL_DTYPE, FREE

ORDER = ("edgetpu", "litert-cpu", "onnxruntime-cpu")
SIZE = OBSERVATION_WINDOW_CELLS
G = GOAL_GRID_CELLS


def nearest_first_scores() -> np.ndarray:
    """Goal-cell scores that prefer the cells nearest the vehicle (the grid's centre): a Nearest-Frontier policy."""
    rows, cols = np.mgrid[0:G, 0:G] - G // 2
    return -np.hypot(rows, cols).astype(np.float32)


def write_policy_model(
    folder: Path,
    scores: np.ndarray | None = None,
    names: tuple[str, str, str] = ("high", "thres", "last_action"),
    output_cells: int = G,
) -> Path:
    """A ``policy`` model folder (ONNX + card) whose goal scores are ``scores`` (default :func:`nearest_first_scores`)
    plus the last action's index (so the test sees the observation reach the model) plus 0 × the windows' means.
    Returns the card's path."""
    folder.mkdir(parents=True, exist_ok=True)
    high, thres, last = names
    bias = (nearest_first_scores() if scores is None else scores)[:output_cells, :output_cells][None]
    action_index = np.arange(NUM_ACTIONS, dtype=np.float32).reshape(NUM_ACTIONS, 1)
    map_shape = [1, SIZE, SIZE]
    graph = helper.make_graph(
        [
            helper.make_node("MatMul", [last, "action_index"], ["last_id"]),  # [1, 1]
            helper.make_node("ReduceMean", [high], ["high_mean"], axes=[1, 2], keepdims=0),
            helper.make_node("ReduceMean", [thres], ["thres_mean"], axes=[1, 2], keepdims=0),
            helper.make_node("Add", ["high_mean", "thres_mean"], ["maps_mean"]),
            helper.make_node("Mul", ["maps_mean", "zero"], ["nothing"]),  # the windows are inputs, unused
            helper.make_node("Add", ["last_id", "nothing"], ["shift"]),
            helper.make_node("Unsqueeze", ["shift", "one_axis"], ["shift3"]),  # [1, 1, 1]
            helper.make_node("Add", ["bias", "shift3"], ["logits"]),
        ],
        "tiny-goal-policy",
        [
            helper.make_tensor_value_info(high, TensorProto.FLOAT, map_shape),
            helper.make_tensor_value_info(thres, TensorProto.FLOAT, map_shape),
            helper.make_tensor_value_info(last, TensorProto.FLOAT, [1, NUM_ACTIONS]),
        ],
        [helper.make_tensor_value_info("logits", TensorProto.FLOAT, [1, output_cells, output_cells])],
        [
            helper.make_tensor("bias", TensorProto.FLOAT, bias.shape, bias.ravel()),
            helper.make_tensor("action_index", TensorProto.FLOAT, action_index.shape, action_index.ravel()),
            helper.make_tensor("zero", TensorProto.FLOAT, [], [0.0]),
            helper.make_tensor("one_axis", TensorProto.INT64, [1], [2]),
        ],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)], ir_version=8)
    onnx.checker.check_model(model)
    path = folder / "policy_fp32.onnx"
    onnx.save(model, path)
    inputs = [TensorSpec(n, tuple(s), "float32") for n, s in zip(names, (map_shape, map_shape, [1, 6]), strict=True)]
    output = TensorSpec("logits", (1, output_cells, output_cells), "float32")
    card = folder / "card.json"
    write_card(card, "policy", [ArtifactCard.describe(path, "onnx", inputs, [output])])
    return card


def observation(last_action: int) -> dict[str, np.ndarray]:
    """The shared observation of a free map (the robot in the middle of it)."""
    high = np.full((60, 60), FREE, dtype=CELL_DTYPE)
    low = np.full((15, 15), FREE, dtype=CELL_DTYPE)
    return observation_from_maps(high, low, 0.05, 0.20, (30, 30), (7, 7), 0.4, last_action)


def test_the_observation_reaches_the_model_and_the_scores_come_back_as_the_goal_grid(tmp_path):
    policy = PolicyRuntime(load_model(write_policy_model(tmp_path / "policy"), ORDER))
    assert policy.model.backend.name == "onnxruntime-cpu" and "policy" in policy.model.report
    for last in Action:
        scores = policy.scores(observation(last))
        assert scores.shape == (G, G) and scores.dtype == np.float32
        np.testing.assert_allclose(scores, nearest_first_scores() + int(last), atol=1e-5)
        assert np.unravel_index(int(np.argmax(scores)), scores.shape) == (G // 2, G // 2)


def test_inputs_must_be_named_after_the_observation(tmp_path):
    card = write_policy_model(tmp_path / "policy", names=("map_high", "map_thres", "previous"))
    with pytest.raises(PolicyModelError, match="must be named"):
        PolicyRuntime(load_model(card, ORDER))


def test_the_output_must_be_the_goal_grid(tmp_path):
    card = write_policy_model(tmp_path / "policy", output_cells=G - 1)
    with pytest.raises(PolicyModelError, match="goal-cell scores"):
        PolicyRuntime(load_model(card, ORDER))


def test_non_finite_scores_raise(tmp_path):
    policy = PolicyRuntime(load_model(write_policy_model(tmp_path / "nan", np.full((G, G), np.nan)), ORDER))
    with pytest.raises(PolicyModelError, match="not finite"):
        policy.scores(observation(Action.HOVER))
