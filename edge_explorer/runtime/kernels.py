"""The numba kernels of a flight: loaded before take-off, then LLVM's pages handed back.

The daemon's per-frame work (fusion, projection, the coverage count, the follower's swept-path test) and the
simulated depth camera are numba kernels. numba needs LLVM (``libllvmlite.so``, 180 MB on disk) to compile a kernel
or to load its machine code from numba's on-disk cache, and for nothing else: a loaded kernel is a function pointer.
Yet importing numba maps ~65–90 MB of LLVM's code, and loading the kernels touches more; those pages stay in the
process's resident set for the whole flight — the largest single item of the daemon's memory
(docs/runtime/README.md, "Memory").

So a flight does, in this order, before its other imports (pymavlink, LiteRT, the planners, the daemon):

1. :func:`warm_kernels` — every kernel of the flight's loop is called once on one rendered frame of the building,
   with the loop's argument types: numba compiles it (empty cache) or loads it from the cache.
2. :func:`release_llvm_pages` — the process unmaps its resident pages of LLVM's read-only, unmodified mappings
   (``madvise(MADV_DONTNEED)``). They are clean file pages: they stay in the page cache and fault back in if a
   kernel is ever compiled again, so nothing can break — a kernel first called later only costs its load again.

The start pose's child process (:func:`edge_explorer.sim.flight._start_pose`) does step 1 first on a fresh
install, so numba compiles (LLVM's working memory, ~0.5 s) in that child and the daemon only loads.
"""

from __future__ import annotations

import atexit
import ctypes
import logging
import os
import re
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

_MADV_DONTNEED = 4
_warm = False
_released = False
_MAPPING = re.compile(r"^([0-9a-f]+)-([0-9a-f]+) (\S+) \S+ \S+ \S+\s*(.*)$")


def warm_kernels(raster: Any, camera: Callable[[Any], Any] | None = None) -> None:
    """Run each numba kernel of a flight over ``raster`` once, with the flight's argument types: with ``camera``
    (raster → the simulated depth camera, :meth:`edge_explorer.sim.flight.SimulatedFlight.camera`) the camera's
    render, then fusion into both voxel maps, projection, the coverage count, the follower's swept-path test, the
    learned planner's map inflation, the planners' lines of sight and their planning graph (numba keeps one
    machine-code version per argument types, so these calls compile or load exactly those;
    tests/runtime/test_kernels.py checks the default flight loads no other). Without a camera (a real drone's) the
    fusion takes a flat frame of the D435's decimated stream: the same argument types."""
    import numpy as np

    from edge_explorer.mapping.ego import inflate_codes
    from edge_explorer.mapping.growing import GrowingMaps, GrowthConfig
    from edge_explorer.mapping.metrics import map_metrics
    from edge_explorer.mapping.projection import HeightBand
    from edge_explorer.mapping.voxels import FusionConfig
    from edge_explorer.plan.follow import FreeSpace
    from edge_explorer.plan.graph import GraphConfig, PlanningGraph
    from edge_explorer.plan.sight import clear_lines
    from edge_explorer.vehicle.camera import CameraConfig, CameraPose
    from edge_explorer.vehicle.dynamics import swept_path_blocked
    from edge_explorer.world.grid import LOW_RES_M

    band = HeightBand()  # the daemon's defaults (DaemonConfig.band, .fusion)
    grid = raster.grid
    row, col = (int(v) for v in np.argwhere(raster.interior)[0])
    x_m, y_m = (float(v) for v in grid.center_of(row, col))
    pose = CameraPose(x_m, y_m, band.flight_z_m, 0.0)
    if camera is not None:
        renderer = camera(raster)
        intrinsics = renderer.config.intrinsics
        depth_m = renderer.render(pose)
    else:
        intrinsics = CameraConfig().intrinsics
        depth_m = np.full(intrinsics.shape, 2.0, dtype=np.float32)
    # Small boxes around the pose (the flight's grow; the kernels' argument types are the same).
    z_range = (band.min_z_m - LOW_RES_M, band.min_z_m + 1.2)
    maps = GrowingMaps(x_m, y_m, z_range, FusionConfig(), GrowthConfig(window_m=12.0, start_m=2.0), band)
    maps.fuse(depth_m, intrinsics, pose.position_m, pose.rotation_map_from_optical(), 0.0)
    maps.ensure_covers(x_m + 8.0, y_m)  # a growth and a move of the 0.05 m window (its shift kernel)
    maps.project()  # composes the whole 0.05 m map …
    maps.mark_flown(x_m, y_m, 0.2)
    high, high_grid, low, low_grid = maps.project()  # … then the window's and the flown cells in place
    coarse = raster.coarsened(LOW_RES_M)
    truth, interior = coarse.truth_codes(), coarse.interior
    shape = truth.shape
    fill = np.zeros(shape, dtype=low.dtype)
    map_metrics(fill, truth, interior, None)
    map_metrics(fill, truth, interior, np.zeros(shape, dtype=low.dtype))
    swept_path_blocked(np.zeros(high.shape, dtype=bool), high_grid, (x_m, y_m), (x_m, y_m))
    inflate_codes(high, high_grid.resolution_m)  # the learned planner's observation (mapping/ego.py)
    clear_lines(np.zeros(2), np.ones((1, 2)), np.linspace(0.0, 1.0, 3), low == 0, low_grid.origin_xy, 0.2)  # views
    PlanningGraph.build(FreeSpace.from_codes(high, high_grid), 0.3, (x_m, y_m), GraphConfig())  # the planning graph
    global _warm
    _warm = True


def kernels_warm() -> bool:
    """Whether :func:`warm_kernels` ran in this process (its kernels are loaded: argument types do not depend on the
    building)."""
    return _warm


def release_llvm_pages() -> float:
    """Unmap this process's resident pages of ``libllvmlite.so`` that are read-only and unmodified (its code and
    constants; not its data or relocated pages); returns the MB released. 0 where /proc or madvise is missing."""
    try:
        smaps = Path("/proc/self/smaps").read_text()
        libc = ctypes.CDLL(None, use_errno=True)
    except OSError:
        return 0.0
    madvise = libc.madvise
    madvise.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]
    released_kb = 0
    for start, end, perms, rss_kb, anon_kb in _mappings(smaps, "libllvmlite"):
        if "w" in perms or anon_kb or not rss_kb:
            continue  # written (data, relocations): those pages exist only here
        if madvise(start, end - start, _MADV_DONTNEED) == 0:
            released_kb += rss_kb
    global _released
    _released = True
    return released_kb / 1024


def exit_without_native_teardown(code: int) -> None:
    """End the program with ``code`` once its work is done, skipping the native libraries' teardown, where this
    process released LLVM's pages; elsewhere return (the program ends as usual).

    At exit LLVM's static destructors run through its code and fault back ~60 MB of the pages
    :func:`release_llvm_pages` handed back — after the flight, on top of everything the flight still holds, so the
    process's high-water mark rose by ~45 MB in its last milliseconds (docs/runtime/README.md, "Memory"). Here the
    program finishes as Python would — non-daemon threads joined, every ``atexit`` handler run (logging flushed and
    closed, multiprocessing's children joined), stdout and stderr flushed — and then leaves with ``os._exit``, which
    skips the interpreter's module teardown and the C++ destructors. Only for the program's own end (the console
    script, ``python -m``), never for a caller of ``main`` in its own interpreter."""
    if not _released:
        return
    for thread in threading.enumerate():
        if thread is not threading.main_thread() and not thread.daemon:
            thread.join()
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)


def _mappings(smaps: str, name_part: str) -> list[tuple[int, int, str, int, int]]:
    """(start, end, perms, Rss kB, Anonymous kB) of each mapping in ``smaps`` whose path contains ``name_part``."""
    found: list[tuple[int, int, str, int, int]] = []
    current: list[Any] | None = None
    for line in smaps.splitlines():
        head = _MAPPING.match(line)
        if head is not None:
            current = None
            if name_part in head.group(4):
                current = [int(head.group(1), 16), int(head.group(2), 16), head.group(3), 0, 0]
                found.append(current)  # type: ignore[arg-type]
        elif current is not None:
            if line.startswith("Rss:"):
                current[3] = int(line.split()[1])
            elif line.startswith("Anonymous:"):
                current[4] = int(line.split()[1])
    return [tuple(m) for m in found]  # type: ignore[misc]
