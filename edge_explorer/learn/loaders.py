"""The learned models by reference, as the benchmark, the trainers and the export load them: the map predictor
(:func:`load_predictor`) and the goal policy (:func:`load_policy`) — exported folders through the backend chain,
torch weights (the ``train`` extra) or, for the predictor, any Python callable."""

from __future__ import annotations

import importlib
from pathlib import Path

from edge_explorer.backends.card import CARD_FILE
from edge_explorer.errors import EdgeExplorerError
from edge_explorer.plan.goal_policy import GoalPolicy
from edge_explorer.sim.env import Predictor


def load_predictor(reference: str) -> Predictor:
    """The predictor named by ``reference``: a callable from the 256×256 int8 north-up low-res window to occupancy
    probabilities of the same shape (what :class:`~edge_explorer.sim.env.ExplorationEnv` takes).

    ``reference`` is one of

    * a model folder (``models/predictor``) or its ``card.json``: the exported artifacts through the backend chain
      (:func:`~edge_explorer.backends.chain.load_model`, int8 first, each checked against the card), with the
      whole-floor model its card names (``beyond_envelope``) — what the daemon flies;
    * a ``.safetensors`` file of :func:`~edge_explorer.learn.unet.save_unet`: the torch model (needs the ``train``
      extra), for weights that have not been exported yet;
    * ``module:callable``: any Python function, e.g. a test double.
    """
    path = Path(reference)
    if path.suffix == ".safetensors":
        if not path.is_file():
            raise EdgeExplorerError(f"--predictor {reference}: no such file")
        try:
            from edge_explorer.learn.unet import TorchPredictor
        except ImportError as exc:
            raise EdgeExplorerError(
                f"--predictor {reference}: torch weights need the train extra (pip install -e '.[train]'): {exc}"
            ) from exc
        return TorchPredictor.from_file(path)
    if path.is_dir() or path.name == CARD_FILE:
        from edge_explorer.backends.chain import load_model
        from edge_explorer.predict.predictor import PredictorRuntime, card_beyond

        beyond_card = card_beyond(path)  # the whole-floor model the card names, if any
        beyond = None if beyond_card is None else PredictorRuntime(load_model(beyond_card))
        return PredictorRuntime(load_model(path), beyond=beyond)
    module_name, _, attribute = reference.partition(":")
    if not module_name or not attribute:
        raise EdgeExplorerError(
            f"--predictor {reference!r}: expected a model folder with card.json, a .safetensors file or "
            "module:callable (a Python function from the 256×256 low-res window to probabilities)"
        )
    try:
        predictor = getattr(importlib.import_module(module_name), attribute)
    except (ImportError, AttributeError) as exc:
        raise EdgeExplorerError(f"--predictor {reference!r}: cannot load it ({exc})") from exc
    if not callable(predictor):
        raise EdgeExplorerError(f"--predictor {reference!r} is not callable")
    return predictor


def load_policy(reference: str) -> GoalPolicy:
    """The learned goal policy named by ``reference`` as a :data:`~edge_explorer.plan.goal_policy.GoalPolicy`
    (observation → 59 × 59 goal-cell scores), flown by :class:`~edge_explorer.plan.goal_policy.GoalPolicyPlanner`:

    * a ``.safetensors`` of :func:`~edge_explorer.learn.goal_net.save_goal_net` — the torch weights a training run
      writes (``train`` extra);
    * a model folder (``models/policy``) or its ``card.json`` — the exported policy through the backend chain, as the
      daemon runs it.
    """
    path = Path(reference)
    if path.suffix == ".safetensors":
        if not path.is_file():
            raise EdgeExplorerError(f"--policy {reference}: no such file")
        try:
            from edge_explorer.learn.goal_net import TorchGoalPolicy
        except ImportError as exc:
            raise EdgeExplorerError(
                f"--policy {reference}: torch weights need the train extra (pip install -e '.[train]'): {exc}"
            ) from exc
        try:
            return TorchGoalPolicy.from_file(path)
        except ValueError as exc:
            raise EdgeExplorerError(f"--policy {reference}: {exc}") from None
    if path.is_dir() or path.name == CARD_FILE:
        from edge_explorer.backends.chain import load_model
        from edge_explorer.plan.policy import PolicyRuntime

        return PolicyRuntime(load_model(path)).scores
    raise EdgeExplorerError(
        f"--policy {reference!r}: expected a model folder with card.json or a goal-policy .safetensors"
    )
