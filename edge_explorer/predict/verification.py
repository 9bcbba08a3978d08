"""How much of the map is still unverified, from the maps alone: the stop rule of issue #56 (item 3).

A flight without a plan of the building (the daemon on a real drone) cannot measure coverage against N_M
(docs/design.md §7), so it cannot tell when exploration is done the way the benchmark does. This module estimates,
from what the flight has — the observed 0.20 m map, the fused map (observed ∪ thresholded prediction, §5) and the
predictor's occupancy probabilities — how much area the map still *might have wrong or missing*:

**Unknown reachable area.** The *open region* is the 4-connected component(s), holding the observed FREE cells, of
the cells the vehicle could fly to or look into: fused FREE cells (observed or predicted free), and cells not known
free — fused UNKNOWN, or OCCUPIED by prediction only — within ``reach_m`` (default the sensor's 4.5 m range,
measured in 4-connected steps through such cells, so never through a wall) of that free space. Only *observed*
OCCUPIED cells bound it: a predicted wall never seals space off (a doorway predicted shut must not hide the room
behind it). Its fused UNKNOWN cells are the unknown reachable area: space behind a frontier that the vehicle could
still fly into or see. Two things are left out on purpose:

* unknown space sealed off by observed walls (the inside of tall furniture, space outside a closed outer wall): no
  flight can ever see it, so waiting for it would never end — Nearest Frontier's own end;
* unknown space deeper than ``reach_m`` behind the free space: it still counts up to that depth — a room behind a
  doorway counts some 15–20 m², far above the threshold — and the figure stays finite where the map is open to
  the outside (a gap in an outer wall, a map much larger than the building, as in the daemon).

4-connectivity keeps the region from slipping through the diagonal gaps that 0.20 m walls leave at their corners.

**Expected wrong predicted area.** Over the cells known only by prediction (UNKNOWN in the observed map, FREE or
OCCUPIED in the fused map) near the building — in or next to (8-neighbours) the open region (which takes in
predicted walls up to ``reach_m`` from the free space) or the region the fused map encloses (cells the map border
cannot be reached from without crossing a fused OCCUPIED cell) — the sum of P(wrong) × cell area, with P(wrong) =
p_occ for a predicted-free cell and 1 − p_occ for a predicted-occupied one (the predictor's probabilities as the
flight has them; calibrated ones make this an honest expectation). Predicted cells behind observed walls or far out
in the exterior (the predictor paints the outside of a building solid) do not count: the flight neither needs nor
can check them. A prediction that is confidently wrong (p ≈ 1 over a whole unseen room) counts next to nothing:
the rule is only as good as the probabilities' calibration. Without a predictor there are no predicted cells and
the rule is Nearest Frontier's: no reachable unknown space left.

The stop rule: exploration ends when :attr:`UnverifiedArea.total_m2` is below a threshold (m²), chosen on the
validation split (:data:`DEFAULT_STOP_THRESHOLD_M2`). Pure numpy + OpenCV, on-device (docs/design.md §2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from edge_explorer.world.grid import FREE, OCCUPIED, UNKNOWN

DEFAULT_REACH_M = 4.5  # depth behind the free space up to which unseen space counts: the sensor range

# The map stop rule's threshold on UnverifiedArea.total_m2, m². Chosen on the generated val split (never test, A-D
# or the real plans): scripts/stop_threshold_sweep.py flew val plans 0-19 × 1 run with frontier, frontier+pred,
# predfrontier+pred and drl+pred; false stops (correct coverage < 90 % at the stop) stayed at 0-1 of 20 per method
# (1 of 80 in all: drl+pred on val-00003, a room the predictor paints solid with confidence) from 2 to 8 m² and first
# rose at 10 m² (drl+pred 2/20, frontier+pred 1/20); 6 m² keeps two steps of margin below that and ends the
# predictor methods 29-36 m before Nearest Frontier's own end (docs/bench/README.md, "The map stop rule").
# Re-flown with the calibrated probabilities the shipped predictor gives since its card carries a calibration: false
# stops stay at 0-1 of 20 per method up to 10 m² and first rise at 12 m², so 6 m² was kept.
DEFAULT_STOP_THRESHOLD_M2 = 6.0


@dataclass(frozen=True)
class UnverifiedArea:
    """What the maps alone say is still unverified, m² (module docstring)."""

    unknown_reachable_m2: float  # UNKNOWN cells of the open region
    expected_wrong_m2: float  # Σ P(wrong) × cell area over the predicted cells near the building
    predicted_m2: float  # area of those predicted cells
    verified_m2: float  # observed known cells of the open region and next to it: what the sensor has confirmed

    @property
    def total_m2(self) -> float:
        return self.unknown_reachable_m2 + self.expected_wrong_m2


def open_region(observed_low: np.ndarray, fused_low: np.ndarray, resolution_m: float, reach_m: float) -> np.ndarray:
    """Bool mask: the open region of the module docstring (empty when nothing is observed free).

    A flood from the observed FREE cells, 4-connected: through fused FREE cells without limit, into cells not known
    free — fused UNKNOWN, or OCCUPIED by prediction only — up to ``reach_m`` (counted in 4-connected steps, so it
    never measures through a wall) from the free space it came from; a free area it meets there joins and the flood
    goes on from it. Only observed OCCUPIED cells stop it."""
    free = (fused_low == FREE).astype(np.uint8)
    limited = ((fused_low != FREE) & (observed_low != OCCUPIED)).astype(np.uint8)
    steps = max(int(round(reach_m / resolution_m)), 0)
    _, free_labels = cv2.connectedComponents(free, connectivity=4)
    cross = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
    joined = np.zeros(fused_low.shape, dtype=bool)
    labels = np.unique(free_labels[observed_low == FREE])
    region = np.zeros(fused_low.shape, dtype=np.uint8)
    while True:
        labels = labels[labels > 0]
        if labels.size == 0:
            return region.astype(bool)
        joined |= np.isin(free_labels, labels)
        region = joined.astype(np.uint8)
        for _ in range(steps):  # geodesic dilation into the unknown, one 4-connected step at a time
            grown = cv2.dilate(region, cross) & (limited | region)
            if np.array_equal(grown, region):
                break
            region = grown
        touched = cv2.dilate(region, cross).astype(bool)
        labels = np.unique(free_labels[touched & ~joined & (free > 0)])


def enclosed_region(fused_low: np.ndarray) -> np.ndarray:
    """Bool mask: cells not 4-connected to the map's border through cells that are not fused OCCUPIED — inside the
    outline the fused map draws (empty while that outline has a gap)."""
    open_cells = (fused_low != OCCUPIED).astype(np.uint8)
    _, labels = cv2.connectedComponents(open_cells, connectivity=4)
    border = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    return (open_cells > 0) & ~np.isin(labels, border)


def unverified_area_m2(
    observed_low: np.ndarray,
    fused_low: np.ndarray,
    probabilities: np.ndarray | None,
    resolution_m: float,
    reach_m: float = DEFAULT_REACH_M,
) -> UnverifiedArea:
    """The unverified area of a flight's maps (module docstring).

    ``observed_low``: int8 codes of the observed 0.20 m map; ``fused_low``: observed ∪ thresholded prediction on the
    same grid (the observed map itself without a predictor); ``probabilities``: the predictor's occupancy
    probabilities on that grid (NaN where it did not predict), None without a predictor. Before any cell is
    observed free the unknown reachable area is infinite: nothing has been verified, so the rule cannot stop."""
    if observed_low.shape != fused_low.shape:
        raise ValueError(f"observed {observed_low.shape} and fused {fused_low.shape} maps differ in shape")
    if probabilities is not None and probabilities.shape != fused_low.shape:
        raise ValueError(f"probabilities {probabilities.shape} and the maps {fused_low.shape} differ in shape")
    cell_m2 = resolution_m**2
    if not (observed_low == FREE).any():  # nothing seen free yet: nothing can be called verified
        return UnverifiedArea(math.inf, 0.0, 0.0, 0.0)
    region = open_region(observed_low, fused_low, resolution_m, reach_m)
    unknown_m2 = float(np.count_nonzero(region & (fused_low == UNKNOWN))) * cell_m2
    near = cv2.dilate((region | enclosed_region(fused_low)).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    verified_m2 = float(np.count_nonzero(near & (observed_low != UNKNOWN))) * cell_m2
    predicted = near & (observed_low == UNKNOWN) & (fused_low != UNKNOWN)
    if probabilities is None or not predicted.any():
        return UnverifiedArea(unknown_m2, 0.0, 0.0, verified_m2)
    p = np.nan_to_num(probabilities[predicted].astype(np.float64), nan=0.5)  # no prediction: a coin toss
    wrong = np.where(fused_low[predicted] == OCCUPIED, 1.0 - p, p)
    return UnverifiedArea(
        unknown_m2,
        float(np.clip(wrong, 0.0, 1.0).sum()) * cell_m2,
        float(np.count_nonzero(predicted)) * cell_m2,
        verified_m2,
    )
