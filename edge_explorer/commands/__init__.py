"""The subcommands of ``edge-explorer`` (:mod:`edge_explorer.cli`), one argparse module per pipeline stage, each with
a ``register(subparsers)`` function. The top layer of the package: a command module may import any stage; no stage
imports a command module."""
