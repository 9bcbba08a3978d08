"""One clearance, one truth (issue #18): the loader, N_M, the start sampler and the planner agree on what a flight
can reach and see, for a passage between the robot's diameter and the planning clearance and one narrower than
the robot."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from edge_explorer.plan.follow import FreeSpace
from edge_explorer.plan.graph import PlanningGraph
from edge_explorer.sim.env import EnvConfig, ExplorationEnv
from edge_explorer.world.flight_space import FLIGHT_CLEARANCE, observable_cells, reachable_cells
from edge_explorer.world.grid import LOW_RES_M
from edge_explorer.world.mapserver import load_map_server

PX = 0.05  # m per pixel
ORIGIN_X_M, ORIGIN_Y_M = 0.0, 0.0


def _two_rooms(tmp_path: Path, passage_px: int, thick_wall: bool = False) -> Path:
    """Rooms of 3 m × 3 m left and right of a 0.10 m wall whose only opening is ``passage_px`` pixels wide, in the
    middle; optionally a solid 0.6 m pillar in the left room (a wall too thick to see inside)."""
    img = np.full((64, 126), 254, np.uint8)  # 2 px outer walls around 60 × 120 px of floor
    img[:2, :] = img[-2:, :] = 0
    img[:, :2] = img[:, -2:] = 0
    img[:, 62:64] = 0
    top = 32 - passage_px // 2
    img[top : top + passage_px, 62:64] = 254
    if thick_wall:
        img[10:22, 10:22] = 0
    cv2.imwrite(str(tmp_path / "m.pgm"), img)
    path = tmp_path / "m.yaml"
    path.write_text(f"image: m.pgm\nresolution: {PX}\norigin: [{ORIGIN_X_M}, {ORIGIN_Y_M}, 0.0]\nnegate: 0\n")
    return path


def _xy(raster, col_px: int, row_px: int) -> tuple[float, float]:
    """Map coordinates of image pixel (row from the top, col), via the raster's grid (the loader pads a margin)."""
    margin = round(0.4 / PX)
    row = raster.grid.shape[0] - 1 - (row_px + margin)
    x, y = raster.grid.center_of(row, col_px + margin)
    return float(x), float(y)


def _planner_connects(raster, a_xy, b_xy) -> bool:
    free = FreeSpace.from_codes(raster.truth_codes(), raster.grid)
    graph = PlanningGraph.build(free, FLIGHT_CLEARANCE.safe_distance_m, a_xy, _graph_config())
    from scipy.sparse.csgraph import connected_components

    _, labels = connected_components(graph.graph, directed=False)
    a, b = graph.node_at(*a_xy), graph.node_at(*b_xy)
    return a >= 0 and b >= 0 and labels[a] == labels[b]


def _graph_config():
    from edge_explorer.plan.graph import GraphConfig

    return GraphConfig()


@pytest.mark.parametrize(
    ("passage_px", "label"),
    [(12, "0.60 m: wider than the robot (0.50 m), narrower than the planning clearance"), (8, "0.40 m: narrower")],
)
def test_loader_n_m_start_sampler_and_planner_agree_on_a_narrow_passage(tmp_path, passage_px, label):
    raster = load_map_server(_two_rooms(tmp_path, passage_px)).raster
    left, right = _xy(raster, 30, 32), _xy(raster, 95, 32)
    reachable = reachable_cells(raster)

    def at(mask, xy):
        return bool(mask[tuple(int(v) for v in raster.grid.cell_of(*xy))])

    # the loader: the start room is reachable, the far room is not (the planner never crosses the passage) …
    assert at(reachable, left) and not at(reachable, right), label
    assert not _planner_connects(raster, left, right), label
    # … N_M keeps what can be seen through the opening and drops what cannot (beside the partition, far room side)
    assert at(raster.interior, _xy(raster, 70, 32)), label
    assert not at(raster.interior, _xy(raster, 66, 4)) and not at(raster.interior, _xy(raster, 66, 59)), label
    assert raster.coarsened(LOW_RES_M).interior.sum() < 64 * 126 / 16
    # the start sampler draws only reachable poses and refuses one in the far room
    env = ExplorationEnv([raster], EnvConfig(motion_noise=False))
    for seed in range(20):
        env.reset(seed=seed)
        assert at(reachable, env.pose[:2])
    with pytest.raises(ValueError, match="reachable flight space"):
        env.reset(options={"start_pose": (*right, 0.0)})


def test_a_wide_door_joins_both_rooms_for_everyone(tmp_path):
    raster = load_map_server(_two_rooms(tmp_path, 20)).raster  # 1.00 m
    left, right = _xy(raster, 30, 32), _xy(raster, 95, 32)
    reachable = reachable_cells(raster)
    assert reachable[tuple(int(v) for v in raster.grid.cell_of(*right))]
    assert _planner_connects(raster, left, right)


def test_inside_of_a_thick_wall_is_not_in_n_m(tmp_path):
    loaded = load_map_server(_two_rooms(tmp_path, 20, thick_wall=True))
    raster = loaded.raster
    inside, face = _xy(raster, 16, 16), _xy(raster, 16, 21)  # the pillar's middle, its bottom face
    assert not raster.interior[tuple(int(v) for v in raster.grid.cell_of(*inside))]
    assert raster.interior[tuple(int(v) for v in raster.grid.cell_of(*face))]
    assert loaded.space.dropped_wall_m2 > 0.2 and loaded.space.dropped_free_m2 < 0.01  # a nook at most


def test_observable_cells_stop_at_walls(tmp_path):
    raster = load_map_server(_two_rooms(tmp_path, 20)).raster
    only_left = np.zeros(raster.grid.shape, dtype=bool)
    row, col = (int(v) for v in raster.grid.cell_of(*_xy(raster, 30, 32)))
    only_left[row, col] = True
    seen = observable_cells(raster, only_left)
    assert seen[tuple(int(v) for v in raster.grid.cell_of(*_xy(raster, 10, 50)))]  # same room, in range
    assert not seen[tuple(int(v) for v in raster.grid.cell_of(*_xy(raster, 100, 5)))]  # behind the wall


def test_view_points_cast_in_blocks_see_the_same_cells(tmp_path, monkeypatch):
    # observable_cells casts its view points in blocks to bound its memory on whole floors: any block size sees the
    # same cells as all view points at once
    import edge_explorer.world.flight_space as flight_space

    raster = load_map_server(_two_rooms(tmp_path, 20)).raster
    reachable = reachable_cells(raster, FLIGHT_CLEARANCE)
    monkeypatch.setattr(flight_space, "_SOURCES_PER_BLOCK", 10**9)
    at_once = observable_cells(raster, reachable)
    monkeypatch.setattr(flight_space, "_SOURCES_PER_BLOCK", 7)
    assert np.array_equal(observable_cells(raster, reachable), at_once)


def test_rays_stop_at_the_maps_border_and_never_wrap_round_it(tmp_path):
    # rays are cast as offsets into the flattened map: one that left a row at its end must not come back on the
    # next row's start; a wall-free map shows the view point only what lies within range on its own side
    from dataclasses import replace

    raster = load_map_server(_two_rooms(tmp_path, 20)).raster
    open_map = replace(raster, height_m=np.zeros_like(raster.height_m))
    range_cells = round(4.5 / raster.grid.resolution_m)
    assert raster.grid.shape[1] > range_cells + 20
    for row in (0, raster.grid.shape[0] // 2, raster.grid.shape[0] - 1):
        view_point = np.zeros(raster.grid.shape, dtype=bool)
        view_point[row, 0] = True
        seen = observable_cells(open_map, view_point)
        assert seen[row, range_cells - 2]  # in range along the row
        assert not seen[:, range_cells + 2 :].any()  # beyond range, on either side of the border
