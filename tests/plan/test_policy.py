"""The policy runtime wrapper on a tiny ONNX model built here (edge_explorer.plan.policy)."""

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
from edge_explorer.plan.policy import PolicyModelError, PolicyRuntime
from edge_explorer.sim.dynamics import Action
from edge_explorer.world.grid import CELL_DTYPE, FREE, OCCUPIED

ORDER = ("edgetpu", "litert-cpu", "onnxruntime-cpu")
SIZE = OBSERVATION_WINDOW_CELLS


def write_policy_model(
    folder: Path, names: tuple[str, str, str] = ("high", "thres", "last_action"), always: int | None = None
) -> Path:
    """A ``policy`` model folder (ONNX + card): the action after the last one, (last + 1) mod 6 — unless the
    ``high`` window is mostly OCCUPIED, then hover; with ``always``, that action whatever it sees. Returns the card's
    path."""
    folder.mkdir(parents=True, exist_ok=True)
    high, thres, last = names
    shift = np.roll(np.eye(NUM_ACTIONS, dtype=np.float32), 1, axis=1)  # one-hot k → one-hot (k + 1) mod 6
    hover_bias = np.zeros((1, NUM_ACTIONS), dtype=np.float32)
    hover_bias[0, Action.HOVER] = 100.0
    if always is not None:
        shift = np.tile(np.eye(NUM_ACTIONS, dtype=np.float32)[always], (NUM_ACTIONS, 1))  # any one-hot → always
        hover_bias[:] = 0.0
    map_shape = [1, SIZE, SIZE]
    graph = helper.make_graph(
        [
            helper.make_node("MatMul", [last, "shift"], ["next"]),
            helper.make_node("ReduceMean", [high], ["occupied_share"], axes=[1, 2], keepdims=0),
            helper.make_node("ReduceMean", [thres], ["thres_mean"], axes=[1, 2], keepdims=0),
            helper.make_node("Mul", ["thres_mean", "zero"], ["thres_term"]),  # thres is an input, unused
            helper.make_node("Add", ["occupied_share", "thres_term"], ["signed_share"]),
            helper.make_node("Relu", ["signed_share"], ["share"]),  # FREE cells (−1) do not count against hover
            helper.make_node("Unsqueeze", ["share", "one_axis"], ["share_col"]),
            helper.make_node("Mul", ["share_col", "hover_bias"], ["hover"]),
            helper.make_node("Add", ["next", "hover"], ["logits"]),
        ],
        "tiny-policy",
        [
            helper.make_tensor_value_info(high, TensorProto.FLOAT, map_shape),
            helper.make_tensor_value_info(thres, TensorProto.FLOAT, map_shape),
            helper.make_tensor_value_info(last, TensorProto.FLOAT, [1, NUM_ACTIONS]),
        ],
        [helper.make_tensor_value_info("logits", TensorProto.FLOAT, [1, NUM_ACTIONS])],
        [
            helper.make_tensor("shift", TensorProto.FLOAT, shift.shape, shift.ravel()),
            helper.make_tensor("hover_bias", TensorProto.FLOAT, hover_bias.shape, hover_bias.ravel()),
            helper.make_tensor("zero", TensorProto.FLOAT, [], [0.0]),
            helper.make_tensor("one_axis", TensorProto.INT64, [1], [1]),
        ],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)], ir_version=8)
    onnx.checker.check_model(model)
    path = folder / "policy_fp32.onnx"
    onnx.save(model, path)
    inputs = [TensorSpec(n, tuple(s), "float32") for n, s in zip(names, (map_shape, map_shape, [1, 6]), strict=True)]
    card = folder / "card.json"
    write_card(card, "policy", [ArtifactCard.describe(path, "onnx", inputs, [TensorSpec("logits", (1, 6), "float32")])])
    return card


def observation(last_action: int, high_code: int = FREE) -> dict[str, np.ndarray]:
    """The shared observation of a uniform map (the robot in the middle of it)."""
    codes = np.full((60, 60), high_code, dtype=CELL_DTYPE)
    low = np.full((15, 15), FREE, dtype=CELL_DTYPE)
    return observation_from_maps(codes, low, 0.05, 0.20, (30, 30), (7, 7), 0.4, last_action)


def test_the_observation_reaches_the_model_and_the_argmax_is_the_action(tmp_path):
    policy = PolicyRuntime(load_model(write_policy_model(tmp_path / "policy"), ORDER))
    assert policy.model.backend.name == "onnxruntime-cpu" and "policy" in policy.model.report
    for last in Action:
        assert policy.act(observation(last)) == (last + 1) % NUM_ACTIONS
    # Occupied cells fill the 60×60 map, a sixteenth of the 237×237 window: the share is enough to make it hover.
    occupied = observation(Action.FORWARD, OCCUPIED)
    assert (occupied["high"] == OCCUPIED).mean() > 0.05
    assert policy.act(occupied) == Action.HOVER
    constant = PolicyRuntime(load_model(write_policy_model(tmp_path / "forward", always=Action.FORWARD), ORDER))
    assert {constant.act(occupied), constant.act(observation(Action.HOVER))} == {Action.FORWARD}


def test_inputs_must_be_named_after_the_observation(tmp_path):
    card = write_policy_model(tmp_path / "policy", names=("map_high", "map_thres", "previous"))
    with pytest.raises(PolicyModelError, match="must be named"):
        PolicyRuntime(load_model(card, ORDER))


def test_an_action_id_answered_directly_is_taken(tmp_path):
    folder = tmp_path / "policy"
    folder.mkdir()
    graph = helper.make_graph(
        [
            helper.make_node("ReduceMean", ["high"], ["h"], axes=[1, 2], keepdims=0),
            helper.make_node("ReduceMean", ["thres"], ["t"], axes=[1, 2], keepdims=0),
            helper.make_node("ArgMax", ["last_action"], ["arg"], axis=1, keepdims=1),
            helper.make_node("Cast", ["arg"], ["arg_f"], to=TensorProto.FLOAT),
            helper.make_node("Add", ["h", "t"], ["ht"]),
            helper.make_node("Mul", ["ht", "zero"], ["nothing"]),
            helper.make_node("Add", ["arg_f", "nothing"], ["action"]),
        ],
        "id-policy",
        [
            helper.make_tensor_value_info("high", TensorProto.FLOAT, [1, SIZE, SIZE]),
            helper.make_tensor_value_info("thres", TensorProto.FLOAT, [1, SIZE, SIZE]),
            helper.make_tensor_value_info("last_action", TensorProto.FLOAT, [1, NUM_ACTIONS]),
        ],
        [helper.make_tensor_value_info("action", TensorProto.FLOAT, [1, 1])],
        [helper.make_tensor("zero", TensorProto.FLOAT, [], [0.0])],
    )
    path = folder / "policy.onnx"
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)], ir_version=8), path)
    specs = [
        TensorSpec("high", (1, SIZE, SIZE), "float32"),
        TensorSpec("thres", (1, SIZE, SIZE), "float32"),
        TensorSpec("last_action", (1, 6), "float32"),
    ]
    write_card(
        folder / "card.json",
        "policy",
        [ArtifactCard.describe(path, "onnx", specs, [TensorSpec("action", (1, 1), "float32")])],
    )
    policy = PolicyRuntime(load_model(folder / "card.json", ORDER))
    assert policy.act(observation(Action.TURN_LEFT_FORWARD)) == Action.TURN_LEFT_FORWARD
