"""The ``edge-explorer`` command line.

Each pipeline stage owns its subcommands in its own ``cli`` module with a ``register(subparsers)`` function;
handlers import their heavy dependencies lazily so ``edge-explorer --help`` and the daemon stay light.
A user error (:class:`~edge_explorer.errors.EdgeExplorerError`) prints one line and exits with code 2.
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from edge_explorer.errors import EdgeExplorerError

# One module per stage; each defines ``register(subparsers: argparse._SubParsersAction) -> None``.
COMMAND_MODULES: tuple[str, ...] = (
    "edge_explorer.world.cli",
    "edge_explorer.sim.cli",
    "edge_explorer.mapping.cli",
    "edge_explorer.learn.cli",
    "edge_explorer.bench.cli",
    "edge_explorer.runtime.cli",
    "edge_explorer.export.cli",
    "edge_explorer.profiling.cli",
)

EXIT_USAGE = 2


class _Parser(argparse.ArgumentParser):
    """argparse that reports bad arguments on one line with exit code 2 (its default code, shorter text)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def positive_int(text: str) -> int:
    """argparse type for counts: a positive integer, with a one-line error otherwise."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="edge-explorer", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser, required=True)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def write_json(path: str | Path | None, payload: Any) -> None:
    """Write a command's machine-readable figures (``--json PATH``); parent folders are created."""
    if path is None:
        return
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(payload, indent=2, default=_json_default) + "\n")


def _json_default(obj: Any) -> Any:
    if hasattr(obj, "tolist"):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"cannot serialise {type(obj).__name__} to JSON")


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        code = int(args.func(args) or 0)
    except EdgeExplorerError as exc:
        print(f"edge-explorer: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("edge-explorer: interrupted", file=sys.stderr)
        return 130
    if argv is None:  # the program itself (console script, python -m), not a caller in its own interpreter
        from edge_explorer.runtime.kernels import exit_without_native_teardown

        exit_without_native_teardown(code)  # a flight skips LLVM's destructors (runtime/kernels.py)
    return code


if __name__ == "__main__":
    sys.exit(main())
