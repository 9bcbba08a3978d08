"""Pictures of buildings: one plan as a PNG, and contact sheets to see a dataset's variety at a glance."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from edge_explorer.world.plan import TALL_HEIGHT_M
from edge_explorer.world.raster import PlanRaster

# RGB colours: outside, free interior, wall / tall obstacle, low furniture.
_OUTSIDE = (200, 205, 215)
_FREE = (255, 255, 255)
_TALL = (25, 25, 30)
_LOW = (214, 170, 110)
_DROPPED = (220, 40, 40)  # left out of N_M: no flight can reach or see it


def plan_rgb(raster: PlanRaster, dropped: np.ndarray | None = None) -> np.ndarray:
    """An RGB image of the raster, rows flipped so +y points up as on a map; ``dropped`` cells (bool) in red."""
    img = np.empty(raster.grid.shape + (3,), dtype=np.uint8)
    img[:] = _OUTSIDE
    img[raster.interior] = _FREE
    low = (raster.height_m > 0) & (raster.height_m < TALL_HEIGHT_M)
    img[low] = _LOW
    img[raster.height_m >= TALL_HEIGHT_M] = _TALL
    if dropped is not None:
        img[dropped] = _DROPPED
    return img[::-1]


def _draw(ax, raster: PlanRaster, title: str, dropped: np.ndarray | None = None) -> None:
    g = raster.grid
    x0, y0 = g.origin_xy
    w, h = g.size_xy_m
    ax.imshow(plan_rgb(raster, dropped), extent=(x0, x0 + w, y0, y0 + h), interpolation="nearest")
    ax.set_title(title, fontsize=8)
    ax.set_xticks([])
    ax.set_yticks([])


def save_plan_png(
    raster: PlanRaster, path: str | Path, title: str | None = None, dropped: np.ndarray | None = None
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    w, h = raster.grid.size_xy_m
    fig, ax = plt.subplots(figsize=(max(4.0, w / 2.2), max(3.0, h / 2.2) + 0.4), dpi=120)
    _draw(ax, raster, title or f"{raster.name}  ({w:.1f} m × {h:.1f} m)", dropped)
    ax.set_xticks(np.arange(np.ceil(raster.grid.origin_xy[0]), raster.grid.origin_xy[0] + w, 2.0))
    ax.set_xlabel("x [m]")
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)


def save_contact_sheet(
    rasters: Sequence[PlanRaster], path: str | Path, titles: Sequence[str] | None = None, cols: int = 4
) -> None:
    """A grid of plans, each titled with its name (and whatever ``titles`` adds)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = -(-len(rasters) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(cols * 4.2, rows * 2.6), dpi=110, squeeze=False)
    for k, ax in enumerate(axes.ravel()):
        if k < len(rasters):
            _draw(ax, rasters[k], titles[k] if titles else rasters[k].name)
        else:
            ax.axis("off")
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
