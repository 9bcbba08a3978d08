"""Map a function over units of work: in this process, in a local process pool, or as Ray tasks (``--ray``).

Every command that fans out (``plans generate``, ``train predictor-data``, ``bench explore``, ``eval predictor``,
``eval policy``) hands its list of unfinished units to :func:`map_units` and gets ``(index, result)`` pairs back as
units finish, in any order; it keeps its own files (per-unit records or shard markers) and so its own resumability,
whichever engine ran the units. A unit whose worker process dies is run again (up to ``max_retries`` times); a
unit that raises stops the command with that error, as in one process.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterator, Sequence
from typing import Any, TypeVar

U = TypeVar("U")
R = TypeVar("R")

MAX_RETRIES = 3  # runs of a unit whose worker died, beyond the first


def add_ray_argument(parser: argparse.ArgumentParser) -> None:
    """The ``--ray auto|ADDRESS`` option of the commands that fan out."""
    parser.add_argument(
        "--ray",
        metavar="auto|ADDRESS",
        help="run the units as Ray tasks (extra: cluster): auto = the cluster started on this machine with `ray "
        "start`, else a local one; ADDRESS = a head's host:port. --workers is then ignored",
    )


def map_units(
    function: Callable[[U], R],
    units: Sequence[U],
    *,
    workers: int = 1,
    ray: str | None = None,
    initializer: Callable[..., None] | None = None,
    initargs: tuple[Any, ...] = (),
    start_method: str | None = None,
    max_retries: int = MAX_RETRIES,
) -> Iterator[tuple[int, R]]:
    """``(k, function(units[k]))`` for every unit, as each finishes.

    With ``ray`` (a Ray address or ``"auto"``) the units run as Ray tasks; otherwise in ``workers`` processes
    (``start_method``: multiprocessing's, e.g. ``"spawn"``; None = the platform's default), or in this process when
    ``workers`` ≤ 1 or there is at most one unit. ``initializer(*initargs)`` runs once in every process that runs
    units (this one included, in-process) before its first unit. ``function``, ``units`` and ``initargs`` must be
    picklable (module-level functions) when they leave this process.
    """
    if not units:
        return iter(())
    if ray is not None:
        from edge_explorer.cluster.ray_tasks import ray_map

        return ray_map(function, units, ray, initializer, initargs, max_retries)
    if workers <= 1 or len(units) == 1:
        return _in_process(function, units, initializer, initargs)
    from edge_explorer.cluster.local_pool import pool_map

    return pool_map(function, units, workers, initializer, initargs, start_method, max_retries)


def _in_process(
    function: Callable[[U], R], units: Sequence[U], initializer: Callable[..., None] | None, initargs: tuple[Any, ...]
) -> Iterator[tuple[int, R]]:
    if initializer is not None:
        initializer(*initargs)
    for k, unit in enumerate(units):
        yield k, function(unit)
