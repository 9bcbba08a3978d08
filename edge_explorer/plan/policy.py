"""The learned goal policy at run time: the policy observation in, 59 × 59 goal-cell scores out (no torch).

The observation is the one every stage builds with :func:`~edge_explorer.mapping.ego.observation_from_maps`
(docs/design.md §5): ``high`` and ``thres`` (237 × 237 heading-up code windows) and ``last_action`` (the one-hot of 6).
The exported model (ONNX or TFLite, loaded and checked against its card by
:func:`~edge_explorer.backends.chain.load_model`) follows this contract:

* **inputs** are named after the observation's keys, ``high``, ``thres`` and ``last_action``; each takes its array
  as it is (the codes −1, 0, 1, 2 and the one-hot), reshaped to the input's shape from the card; the backend
  converts it to the input's type (float32 in ONNX, quantized int8 in TFLite) — any other preprocessing belongs
  inside the exported graph, so the daemon and the simulator cannot disagree about it;
* **output**: one output of 59 × 59 values, the goal-cell logits of :mod:`edge_explorer.plan.goal_grid`; the goal is
  their argmax over the valid cells (:func:`~edge_explorer.plan.goal_policy.weighted_scores`, with the view-gain term
  :func:`~edge_explorer.plan.goal_policy.with_view_gain`), among the goals worth a look
  (:func:`~edge_explorer.plan.goal_policy.best_cell_worth_a_look`).

:meth:`PolicyRuntime.scores` is a :data:`~edge_explorer.plan.goal_policy.GoalPolicy`, so the exported policy flies
through :class:`~edge_explorer.plan.goal_policy.GoalPolicyPlanner` exactly as the torch weights do in training.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from edge_explorer.backends.base import TensorSpec
from edge_explorer.backends.chain import LoadedModel
from edge_explorer.errors import EdgeExplorerError
from edge_explorer.mapping.ego import NUM_ACTIONS, OBSERVATION_WINDOW_CELLS
from edge_explorer.plan.goal_grid import GOAL_GRID_CELLS

OBSERVATION_SIZES: dict[str, int] = {
    "high": OBSERVATION_WINDOW_CELLS**2,
    "thres": OBSERVATION_WINDOW_CELLS**2,
    "last_action": NUM_ACTIONS,
}
GOAL_SCORES_SHAPE = (GOAL_GRID_CELLS, GOAL_GRID_CELLS)


class PolicyModelError(EdgeExplorerError):
    """The loaded model does not follow the goal policy's input/output contract."""


def _concrete_shape(spec: TensorSpec) -> tuple[int, ...]:
    """The input's shape with dynamic (−1) dimensions — the batch — set to 1."""
    return tuple(1 if d == -1 else d for d in spec.shape)


class PolicyRuntime:
    """An exported goal policy ready to run (see the module docstring)."""

    def __init__(self, model: LoadedModel) -> None:
        inputs = {spec.name: spec for spec in model.backend.inputs}
        if set(inputs) != set(OBSERVATION_SIZES):
            raise PolicyModelError(
                f"{model.name}: policy inputs must be named {sorted(OBSERVATION_SIZES)} (the observation's keys), "
                f"got {sorted(inputs)}"
            )
        self._shapes = {name: _concrete_shape(spec) for name, spec in inputs.items()}
        for name, shape in self._shapes.items():
            if math.prod(shape) != OBSERVATION_SIZES[name]:
                raise PolicyModelError(
                    f"{model.name}: input {name!r} {list(inputs[name].shape)} does not hold the observation's "
                    f"{OBSERVATION_SIZES[name]} values"
                )
        outputs = model.backend.outputs
        if len(outputs) != 1 or math.prod(_concrete_shape(outputs[0])) != math.prod(GOAL_SCORES_SHAPE):
            raise PolicyModelError(
                f"{model.name}: expected one output of {GOAL_GRID_CELLS}×{GOAL_GRID_CELLS} goal-cell scores, got "
                f"{[(s.name, list(s.shape)) for s in outputs]}"
            )
        self._output = outputs[0].name
        self.model = model

    def scores(self, observation: Mapping[str, np.ndarray]) -> np.ndarray:
        """The 59 × 59 goal-cell scores (float32) for one observation dict (``high``, ``thres``, ``last_action``);
        raises :class:`PolicyModelError` when the model answers non-finite scores."""
        feed = {name: np.asarray(observation[name]).reshape(shape) for name, shape in self._shapes.items()}
        out = np.asarray(self.model.run(feed)[self._output], dtype=np.float32).reshape(GOAL_SCORES_SHAPE)
        if not np.isfinite(out).all():
            raise PolicyModelError(f"{self.model.name}: goal scores are not finite")
        return out
