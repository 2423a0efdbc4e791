"""Input/output at the edge: the OpenIGTLink codec, the asyncio navigation server, what the trainer sends
back to its peers, the haptic stream of the reaming force, and the PlusServer device sets that stream the
names it reads."""

from thrsim.io.server import NAVIGATION_STATE, IgtlServer

__all__ = ["NAVIGATION_STATE", "IgtlServer"]
