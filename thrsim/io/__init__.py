"""Input/output at the edge: the OpenIGTLink codec and the asyncio navigation server."""

from thrsim.io.server import NAVIGATION_STATE, IgtlServer

__all__ = ["NAVIGATION_STATE", "IgtlServer"]
