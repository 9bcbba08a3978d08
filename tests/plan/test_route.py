"""The global layer's route (plan/route.py) from a vehicle whose own cell is cut off from the route graph."""

import numpy as np

from edge_explorer.plan.route import RouteConfig, nearest_route
from edge_explorer.world.grid import FREE, OCCUPIED, UNKNOWN, GridSpec


def _slot_between_walls() -> tuple[np.ndarray, GridSpec]:
    """4 × 12 m at 0.20 m: a room east of x = 4 m, a 0.6 m unseen slot between two walls leading west from it, and
    behind the southern wall a closed room, nearer to the slot than the east room's far end."""
    low = np.full((20, 60), UNKNOWN, dtype=np.int8)
    low[:, 20:] = FREE  # the east room
    low[7:9, :20] = OCCUPIED  # the slot's southern wall (rows 9–11 stay unseen)
    low[12:14, :20] = OCCUPIED  # its northern wall
    low[0:7, :19] = FREE  # the closed room behind the southern wall …
    low[0:7, 19] = OCCUPIED  # … walled off from the east room
    return low, GridSpec((0.0, 0.0), 0.2, low.shape)


def test_a_vehicle_cut_off_in_an_unseen_slot_is_routed_out_the_way_the_slot_leads_not_through_a_wall():
    low, grid = _slot_between_walls()
    targets = np.zeros(low.shape, dtype=bool)
    targets[3, 10] = True  # in the closed room, 1.5 m from the vehicle through the wall
    targets[10, 50] = True  # in the east room, 7.6 m away along the slot
    vehicle = (2.5, 2.1)  # cell (10, 12), in the slot
    assert nearest_route(low, grid, targets, vehicle, RouteConfig(escape_m=0.0)) is None  # cut off
    route = nearest_route(low, grid, targets, vehicle, RouteConfig())
    assert route is not None
    assert np.allclose(route.path_xy_m[0], vehicle, atol=0.11)  # it starts at the vehicle's cell
    assert np.ravel_multi_index((10, 50), low.shape) in route.target_cells
    rows, cols = (np.asarray(v) for v in grid.cell_of(route.path_xy_m[:, 0], route.path_xy_m[:, 1]))
    assert (low[rows, cols] != OCCUPIED).all() and (rows[1:] >= 9).all()  # never in or behind a wall


def test_when_no_target_is_reachable_on_the_graph_a_route_may_pass_a_slot_two_cells_wide():
    """Two rooms joined by a slot that shows two FREE cells across on the 0.20 m map (a 0.6–0.8 m door): the graph
    of 0.4 m clearance closes it, so the route to the far room's frontier passes it on the graph of every FREE cell."""
    low = np.full((20, 60), FREE, dtype=np.int8)
    low[:, 28:32] = OCCUPIED  # the wall between the rooms …
    low[9:11, 28:32] = FREE  # … and the slot through it, rows 9–10
    low[:, 59] = UNKNOWN  # the far room's east end is unseen
    targets = np.zeros(low.shape, dtype=bool)
    targets[:, 58] = True
    grid = GridSpec((0.0, 0.0), 0.2, low.shape)
    vehicle = (2.1, 2.1)  # in the west room
    assert nearest_route(low, grid, targets, vehicle, RouteConfig(narrow_clearance_m=0.4)) is None
    route = nearest_route(low, grid, targets, vehicle, RouteConfig())
    assert route is not None and route.path_xy_m[-1, 0] > 11.0
    rows, cols = (np.asarray(v) for v in grid.cell_of(route.path_xy_m[:, 0], route.path_xy_m[:, 1]))
    assert (low[rows, cols] == FREE).all() and set(rows[(cols >= 28) & (cols < 32)]) <= {9, 10}  # through the slot
