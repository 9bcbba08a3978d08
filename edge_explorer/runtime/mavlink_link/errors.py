"""The link's one error type."""

from __future__ import annotations

from edge_explorer.errors import EdgeExplorerError


class LinkError(EdgeExplorerError):
    """The MAVLink link cannot do what was asked: bad configuration, no autopilot, or a command refused."""
