"""Units of work as Ray tasks: connect to a cluster, run each unit as a task, yield results as tasks finish.

Ray is imported here and nowhere else, only when a command is given ``--ray``. ``auto`` is ``ray.init()``'s own
default: the cluster this machine joined with ``ray start`` (or ``RAY_ADDRESS``), else a local one that lives as long
as the command. An address is a head's ``host:port`` (the GCS port ``ray start --head`` prints, 6379 by default).

Each unit is one task of one CPU with Ray's ``max_retries``: a task whose worker process or node dies is run again;
an exception raised by the unit is not retried and reaches the caller as that exception. At most two tasks per
cluster CPU are in flight (Ray's "limit pending tasks" pattern), so a sweep of thousands of units does not put all
their arguments in the object store at once. ``initializer(*initargs)`` runs once per Ray worker process, before its
first unit, as a process pool's initializer would.
"""

from __future__ import annotations

import socket
import sys
from collections.abc import Callable, Iterator, Sequence
from typing import Any, TypeVar

from edge_explorer.errors import EdgeExplorerError

U = TypeVar("U")
R = TypeVar("R")

AUTO = "auto"
CONNECT_TIMEOUT_S = 5.0
TASKS_PER_CPU = 2

_INITIALIZED: set[tuple[Any, ...]] = set()  # per Ray worker process: the initializers already run


def _run_unit(shared: tuple[Callable[[U], R], Callable[..., None] | None, tuple[Any, ...]], unit: U) -> R:
    function, initializer, initargs = shared
    if initializer is not None and (initializer, *initargs) not in _INITIALIZED:
        initializer(*initargs)
        _INITIALIZED.add((initializer, *initargs))
    return function(unit)


def _check_reachable(address: str) -> None:
    """A one-line error now for a ``host:port`` nobody listens on, instead of Ray's minute of retries."""
    host, sep, port = address.rpartition(":")
    if not sep or not port.isdigit():
        raise EdgeExplorerError(f"--ray {address}: expected auto or a Ray head's host:port (e.g. 10.0.0.5:6379)")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=CONNECT_TIMEOUT_S).close()
    except OSError as exc:
        raise EdgeExplorerError(
            f"--ray {address}: no Ray head answers there ({exc}); start one with `ray start --head` on that machine"
        ) from None


def connect(address: str) -> tuple[Any, bool]:
    """``(ray module, whether this call started the connection)``; an already connected driver is reused."""
    try:
        import ray
    except ImportError:
        raise EdgeExplorerError("--ray needs Ray: pip install 'edge-explorer[cluster]'") from None
    if address != AUTO and not address.startswith("ray://"):
        _check_reachable(address)
    if ray.is_initialized():
        return ray, False
    try:
        ray.init(address=None if address == AUTO else address, log_to_driver=True)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        first_line = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise EdgeExplorerError(f"--ray {address}: cannot connect to a Ray cluster ({first_line})") from None
    cpus = int(ray.cluster_resources().get("CPU", 0))
    print(f"Ray cluster: {len(ray.nodes())} node(s), {cpus} CPUs", file=sys.stderr)
    return ray, True


def ray_map(
    function: Callable[[U], R],
    units: Sequence[U],
    address: str,
    initializer: Callable[..., None] | None,
    initargs: tuple[Any, ...],
    max_retries: int,
) -> Iterator[tuple[int, R]]:
    """``(k, function(units[k]))`` as the Ray tasks finish; see the module docstring. Connects now, so a bad
    address fails before any progress bar is drawn."""
    ray, owned = connect(address)
    return _results(ray, owned, function, units, initializer, initargs, max_retries)


def _results(
    ray: Any,
    owned: bool,
    function: Callable[[U], R],
    units: Sequence[U],
    initializer: Callable[..., None] | None,
    initargs: tuple[Any, ...],
    max_retries: int,
) -> Iterator[tuple[int, R]]:
    try:
        task = ray.remote(num_cpus=1, max_retries=max_retries, retry_exceptions=False)(_run_unit)
        shared = ray.put((function, initializer, initargs))
        window = max(1, TASKS_PER_CPU * int(ray.cluster_resources().get("CPU", 1)))
        queue = iter(enumerate(units))
        in_flight: dict[Any, int] = {}
        while True:
            for k, unit in queue:
                in_flight[task.remote(shared, unit)] = k
                if len(in_flight) >= window:
                    break
            if not in_flight:
                return
            done, _ = ray.wait(list(in_flight), num_returns=1)
            for ref in done:
                yield in_flight.pop(ref), _result(ray, ref)
    finally:
        if owned:
            ray.shutdown()


def _result(ray: Any, ref: Any) -> Any:
    """The task's value; a unit's own exception is raised as itself (the worker's traceback chained to it), Ray
    giving up on a task is a one-line error."""
    try:
        return ray.get(ref)
    except ray.exceptions.RayTaskError as exc:
        raise exc.cause from exc
    except ray.exceptions.RayError as exc:
        first_line = str(exc).strip().splitlines()[0]
        raise EdgeExplorerError(f"Ray gave up on a unit after its retries: {first_line}") from None
