"""The ``edge-explorer`` command line.

Each pipeline stage owns its subcommands in its own module of :mod:`edge_explorer.commands` with a
``register(subparsers)`` function; handlers import their heavy dependencies lazily so ``edge-explorer --help`` and
the daemon stay light.
A user error (:class:`~edge_explorer.errors.EdgeExplorerError`) prints one line and exits with code 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from edge_explorer.errors import EdgeExplorerError

# One module per stage; each defines ``register(subparsers: argparse._SubParsersAction) -> None``.
COMMAND_MODULES: tuple[str, ...] = (
    "edge_explorer.commands.world",
    "edge_explorer.commands.sim",
    "edge_explorer.commands.mapping",
    "edge_explorer.commands.learn",
    "edge_explorer.commands.bench",
    "edge_explorer.commands.runtime",
    "edge_explorer.commands.export",
    "edge_explorer.commands.profiling",
)

EXIT_USAGE = 2


class _Parser(argparse.ArgumentParser):
    """argparse that reports bad arguments on one line with exit code 2 (its default code, shorter text)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="edge-explorer", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser, required=True)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


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
