"""Input/output at the edge: the OpenIGTLink codec and the asyncio navigation server."""

from thrsim.io.server import NAVIGATION_STATE, SIMULATED_REAMER, NavigationServer, ReamerSimulator

__all__ = ["NAVIGATION_STATE", "SIMULATED_REAMER", "NavigationServer", "ReamerSimulator"]
