"""Units of work in a local ``concurrent.futures`` process pool that survives a lost worker.

A worker process that dies (killed, out of memory) breaks a ``ProcessPoolExecutor``: every unit still queued or
running fails with ``BrokenProcessPool``. The units that finished before are kept; the others go to a fresh pool,
at most ``max_retries`` times, so a lost worker costs its unit a rerun and nothing is yielded twice.
"""

from __future__ import annotations

import multiprocessing
import sys
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from typing import Any, TypeVar

from edge_explorer.errors import EdgeExplorerError

U = TypeVar("U")
R = TypeVar("R")


def pool_map(
    function: Callable[[U], R],
    units: Sequence[U],
    workers: int,
    initializer: Callable[..., None] | None,
    initargs: tuple[Any, ...],
    start_method: str | None,
    max_retries: int,
) -> Iterator[tuple[int, R]]:
    """``(k, function(units[k]))`` as units finish in ``workers`` processes; see the module docstring."""
    context = multiprocessing.get_context(start_method)
    pending = dict(enumerate(units))
    for attempt in range(max_retries + 1):
        with ProcessPoolExecutor(
            max_workers=min(workers, len(pending)), mp_context=context, initializer=initializer, initargs=initargs
        ) as pool:
            futures = {pool.submit(function, unit): k for k, unit in pending.items()}
            for future in as_completed(futures):
                if isinstance(future.exception(), BrokenProcessPool):
                    continue  # its unit stays pending
                k = futures[future]
                result = future.result()
                del pending[k]
                yield k, result
        if not pending:
            return
        if attempt < max_retries:
            print(f"a worker process died; {len(pending)} unfinished unit(s) go to a fresh pool", file=sys.stderr)
    raise EdgeExplorerError(f"worker processes died {max_retries + 1} times; {len(pending)} unit(s) not finished")
