"""Input/output at the edge: the OpenIGTLink codec and the asyncio navigation server."""

from thrsim.io.server import NAVIGATION_STATE, NavigationServer

__all__ = ["NAVIGATION_STATE", "NavigationServer"]
