"""User-facing errors.

Every error a user can fix (bad file, bad argument, missing artifact) is an ``EdgeExplorerError``: the CLI prints
its message on one line and exits with code 2. Programming errors stay ordinary exceptions.
"""

from __future__ import annotations


class EdgeExplorerError(Exception):
    """An error caused by the user's input; the message says what is wrong and how to fix it."""


class PlanError(EdgeExplorerError, ValueError):
    """A floor plan (vector JSON or ROS map_server map) is malformed or violates the dataset's rules."""
