from pathlib import Path

import cv2
import numpy as np
import pytest

from edge_explorer.errors import PlanError
from edge_explorer.world.catalog import load_building, load_buildings
from edge_explorer.world.flight_space import reachable_cells
from edge_explorer.world.mapserver import load_map_server
from edge_explorer.world.raster import check_connected

REALPLANS = Path(__file__).resolve().parents[3] / "shared" / "data" / "realplans"


def _write_map(tmp_path: Path, pixels: np.ndarray, **overrides) -> Path:
    cv2.imwrite(str(tmp_path / "m.pgm"), pixels)
    fields = {
        "image": "m.pgm",
        "resolution": 0.05,
        "origin": "[1.0, -2.0, 0.0]",
        "negate": 0,
        "occupied_thresh": 0.65,
        "free_thresh": 0.196,
    }
    fields.update(overrides)
    path = tmp_path / "m.yaml"
    path.write_text("".join(f"{k}: {v}\n" for k, v in fields.items() if v is not None))
    return path


def _box_image() -> np.ndarray:
    """A 3 m × 2 m room (60 × 40 px) with 2 px walls, plus a closed 0.5 m closet in the top-right corner."""
    img = np.full((40, 60), 254, np.uint8)
    img[:2, :] = img[-2:, :] = 0
    img[:, :2] = img[:, -2:] = 0
    img[:14, 44:46] = 0  # closet wall (closed: no door)
    img[12:14, 44:] = 0
    return img


def test_loads_interior_origin_and_orientation(tmp_path):
    loaded = load_map_server(_write_map(tmp_path, _box_image()))
    r = loaded.raster
    assert r.grid.resolution_m == 0.05
    # origin is the lower-left pixel, shifted by the outside margin
    row, col = r.grid.cell_of(1.0 + 0.5, -2.0 + 0.5)
    assert r.interior[row, col] and not r.occupied[row, col]
    # image row 0 is the top (largest y): the closet is at the top right, dropped as unreachable
    row, col = r.grid.cell_of(1.0 + 2.8, -2.0 + 1.8)
    assert not r.interior[row, col]
    assert loaded.dropped_free_area_m2 == pytest.approx(0.7 * 0.5, rel=0.5)
    check_connected(r)


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"image": "missing.pgm"}, "image 'missing.pgm' not found"),
        ({"resolution": -0.05}, "resolution must be positive"),
        ({"resolution": None}, "missing key(s) ['resolution']"),
        ({"origin": "[0, 0, 0.5]"}, "rotated origins"),
        ({"free_thresh": 0.9}, "free_thresh < occupied_thresh"),
    ],
)
def test_bad_map_yaml_names_file_and_problem(tmp_path, overrides, message):
    path = _write_map(tmp_path, _box_image(), **overrides)
    with pytest.raises(PlanError) as err:
        load_map_server(path)
    assert str(path) in str(err.value) and message in str(err.value)


def test_negate_flag_inverts(tmp_path):
    loaded = load_map_server(_write_map(tmp_path, 254 - _box_image(), negate=1))
    assert loaded.raster.interior.sum() > 0


@pytest.mark.skipif(not REALPLANS.is_dir(), reason="shared/data/realplans not beside the checkout")
def test_all_real_plans_load_with_one_reachable_space_inside_n_m():
    rasters = load_buildings(str(REALPLANS))
    assert len(rasters) == 14
    for r in rasters:
        reachable = reachable_cells(r)
        assert reachable.sum() * 0.05**2 > 25.0, r.name
        assert not (reachable & ~r.interior).any(), r.name  # every place a flight can go counts in N_M


def test_catalog_errors(tmp_path):
    with pytest.raises(PlanError, match="no such plan"):
        load_building(str(tmp_path / "nope.yaml.txt"))
    with pytest.raises(PlanError, match="holds no plans"):
        load_building(str(tmp_path))
