"""Which shipped models a run flies (:func:`choose_models`): the DRL policy when asked for or flight-ready, the
predictor when it loads, each on the device profile's backend order, and the log lines that say why."""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

from edge_explorer.backends.card import CARD_FILE
from edge_explorer.backends.chain import load_model
from edge_explorer.errors import EdgeExplorerError
from edge_explorer.plan.policy import PolicyRuntime
from edge_explorer.plan.registry import PLANNERS
from edge_explorer.predict.predictor import PredictorRuntime, card_beyond


class ModelSetupError(EdgeExplorerError):
    """The models the user asked for cannot be used."""


@dataclass(frozen=True)
class ModelChoice:
    """The models a run uses, and the log lines that say why."""

    policy: PolicyRuntime | None
    predictor: PredictorRuntime | None
    notes: tuple[str, ...]

    def backends(self) -> dict[str, str | None]:
        """Where each model runs (the run summary's ``backends``), None for a model the run does not use."""
        return {
            "policy": None if self.policy is None else self.policy.model.backend.name,
            "predictor": None if self.predictor is None else self.predictor.model.backend.name,
        }


def _flight_ready(card: Path) -> tuple[bool, str]:
    """(ready, why) from a policy card's ``flight_ready`` record; a card without one is not ready."""
    try:
        record = json.loads(card.read_text()).get("flight_ready")
    except (OSError, ValueError, AttributeError) as exc:
        return False, f"{card} is unreadable ({exc})"
    if not isinstance(record, dict) or not isinstance(record.get("ready"), bool):
        return False, f"{card} records no flight_ready evaluation"
    return record["ready"], str(record.get("why", ""))


def choose_models(
    models_dir: Path,
    planner: str,
    backend_order: tuple[str, ...],
    precision: str = "int8",
    num_threads: int = 1,
    model_orders: Mapping[str, tuple[str, ...]] | None = None,
) -> ModelChoice:
    """Load the shipped models the run can use (see docs/design.md §8 and the module docstring).

    ``planner``: the registry's planners that need no policy (``frontier``, ``predfrontier``, …) never load it;
    ``drl`` needs ``models_dir/policy/card.json`` and fails with :class:`ModelSetupError` (one line)
    when it is missing or cannot be loaded; ``auto`` uses the policy only when its card says it is flight-ready
    (``flight_ready.ready``: the building evaluation of these weights passed, see
    :func:`edge_explorer.learn.goal_card.flight_ready`) and it loads, and the frontier planner otherwise, saying
    why; ``frontier`` never loads the policy. The predictor (``models_dir/predictor/card.json``)
    is used when it loads; otherwise the run goes on without it (coverage = observed) and says why.
    ``model_orders`` (the device profile's per-model orders) replaces ``backend_order`` for the models it names.
    """

    def load(name: str, wrapper: type) -> tuple[object | None, str]:
        """(the wrapped model, its backend report) or (None, why not)."""
        card = models_dir / name / CARD_FILE
        if not card.is_file():
            return None, f"no {name} model: {card} is missing"
        try:
            order = (model_orders or {}).get(name, backend_order)
            model = wrapper(load_model(card, order, precision, num_threads))
        except EdgeExplorerError as exc:
            return None, str(exc)
        return model, model.model.report

    notes: list[str] = []
    policy = None
    policy_card = models_dir / "policy" / CARD_FILE
    if planner in PLANNERS and not PLANNERS[planner].needs_policy:
        notes.append(f"planner: {planner} (asked for)")
    elif planner == "auto" and policy_card.is_file() and not (ready := _flight_ready(policy_card))[0]:
        notes.append(f"planner: frontier (the DRL policy is not flight-ready: {ready[1]}; --planner drl flies it)")
    else:
        policy, said = load("policy", PolicyRuntime)
        if policy is None and planner == "drl":
            raise ModelSetupError(f"--planner drl: {said}")
        notes.append(f"planner: drl ({said})" if policy else f"planner: frontier (no usable DRL policy: {said})")
    predictor, said = load("predictor", PredictorRuntime)
    notes.append(f"predictor: {said}" if predictor else f"predictor: none, coverage counts observed cells ({said})")
    if predictor is not None:
        predictor, said = _with_beyond(predictor, models_dir / "predictor" / CARD_FILE, load)
        notes.append(said)
    return ModelChoice(policy, predictor, tuple(notes))


def _with_beyond(
    predictor: PredictorRuntime, card: Path, load: Callable[[str, type], tuple[object | None, str]]
) -> tuple[PredictorRuntime, str]:
    """The predictor with the whole-floor model its card names (``beyond_envelope``) and the note that says so; the
    predictor alone when the card names none, or the model does not load (then the envelope rule holds: beyond it
    nothing is predicted OCCUPIED)."""
    try:
        beyond_card = card_beyond(card)
    except EdgeExplorerError as exc:
        return predictor, f"whole-floor predictor: none ({exc})"
    if beyond_card is None:
        return predictor, "whole-floor predictor: none (the predictor's card names none)"
    beyond, said = load(beyond_card.parent.name, PredictorRuntime)
    if beyond is None:
        return predictor, f"whole-floor predictor: none ({said})"
    try:
        return PredictorRuntime(predictor.model, predictor.thresholds, beyond=beyond), f"whole-floor predictor: {said}"
    except EdgeExplorerError as exc:
        return predictor, f"whole-floor predictor: none ({exc})"
