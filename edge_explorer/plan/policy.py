"""The DRL exploration policy at run time: the policy observation in, one of the six action ids out (no torch).

The observation is the one the simulator trained with, built by the shared
:func:`~edge_explorer.mapping.ego.observation_from_maps` (DESIGN.md §5): ``high`` and ``thres`` (int8 237×237
heading-up code windows) and ``last_action`` (float32 one-hot of 6). The exported model (ONNX or TFLite, loaded and
checked against its card by :func:`~edge_explorer.backends.chain.load_model`) follows this contract:

* **inputs** are named after the observation's keys, ``high``, ``thres`` and ``last_action``; each takes its array
  as it is (the codes −1, 0, 1, 2 and the one-hot), reshaped to the input's shape from the card; the backend
  converts it to the input's type (float32 or int8 in ONNX, quantized in TFLite: the shipped int8 ONNX takes the
  int8 codes without a copy) — any other preprocessing (one-hot channels, scaling) belongs inside the exported
  graph, so the daemon and the simulator cannot disagree about it;
* **output**: the model's output with 6 values, the action logits (or probabilities) — the action is their argmax,
  the policy's deterministic choice; a model with a single output of one value may answer the action id itself.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from edge_explorer.backends.base import TensorSpec
from edge_explorer.backends.chain import LoadedModel
from edge_explorer.errors import EdgeExplorerError
from edge_explorer.mapping.ego import NUM_ACTIONS, OBSERVATION_WINDOW_CELLS

OBSERVATION_SIZES: dict[str, int] = {
    "high": OBSERVATION_WINDOW_CELLS**2,
    "thres": OBSERVATION_WINDOW_CELLS**2,
    "last_action": NUM_ACTIONS,
}


class PolicyModelError(EdgeExplorerError):
    """The loaded model does not follow the policy's input/output contract."""


def _concrete_shape(spec: TensorSpec) -> tuple[int, ...]:
    """The input's shape with dynamic (−1) dimensions — the batch — set to 1."""
    return tuple(1 if d == -1 else d for d in spec.shape)


class PolicyRuntime:
    """An exported policy ready to run (see the module docstring)."""

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
        sized = [s for s in outputs if math.prod(_concrete_shape(s)) == NUM_ACTIONS]
        if len(sized) == 1:
            self._output, self._answers_id = sized[0].name, False
        elif len(outputs) == 1 and math.prod(_concrete_shape(outputs[0])) == 1:
            self._output, self._answers_id = outputs[0].name, True
        else:
            raise PolicyModelError(
                f"{model.name}: expected one output of {NUM_ACTIONS} action scores (or a single action id), got "
                f"{[(s.name, list(s.shape)) for s in outputs]}"
            )
        self.model = model

    def act(self, observation: Mapping[str, np.ndarray]) -> int:
        """The action id (0–5) for one observation dict (``high``, ``thres``, ``last_action``)."""
        feed = {name: np.asarray(observation[name]).reshape(shape) for name, shape in self._shapes.items()}
        out = np.asarray(self.model.run(feed)[self._output], dtype=np.float32).reshape(-1)
        if self._answers_id:
            action = int(round(float(out[0])))
            if not 0 <= action < NUM_ACTIONS:
                raise PolicyModelError(f"{self.model.name}: answered action {out[0]}, outside 0..{NUM_ACTIONS - 1}")
            return action
        if not np.isfinite(out).all():
            raise PolicyModelError(f"{self.model.name}: action scores are not finite: {out}")
        return int(np.argmax(out))
