"""PlusServer device sets for the optical trackers labs run, streaming the device names thrsim reads.

PLUS (the PLUS toolkit's ``PlusServer``) drives the tracker and serves its tools' transforms over
OpenIGTLink, each TRANSFORM named ``<From>To<To>`` after its transform. The device sets shipped
here (``plus_device_sets/``: an NDI Polaris or Vega, an OptiTrack system run by Motive) name the
tools so that the transforms their server streams are exactly the trainer's device names
(:data:`thrsim.config.KNOWN_TRACKER_DEVICES`), and listen on OpenIGTLink's port
(:data:`thrsim.config.OPENIGTLINK_PORT`). Lasso et al., "PLUS: open-source toolkit for
ultrasound-guided intervention systems", IEEE TBME 61(10), 2014, describe the device set and its
transform repository.
"""

from __future__ import annotations

import xml.etree.ElementTree as ElementTree
from importlib import resources

from thrsim.errors import ThrsimInputError

#: tracker → its device set's file in ``plus_device_sets/``
DEVICE_SETS = {"ndi": "ndi.xml", "optitrack": "optitrack.xml"}


def device_set(tracker: str) -> str:
    """The PlusServer configuration (XML text) for ``tracker`` (one of :data:`DEVICE_SETS`)."""
    if tracker not in DEVICE_SETS:
        raise ThrsimInputError(f"{tracker!r} is not one of {', '.join(DEVICE_SETS)}", "tracker")
    return (resources.files("thrsim.io") / "plus_device_sets" / DEVICE_SETS[tracker]).read_text(encoding="utf-8")


def describe(tracker: str) -> dict:
    """What ``tracker``'s device set serves: its name, the port, the tools and the transforms it streams."""
    root = ElementTree.fromstring(device_set(tracker))
    server, named = root.find("PlusOpenIGTLinkServer"), root.find("DataCollection/DeviceSet")
    if server is None or named is None:
        raise ThrsimInputError(f"the {tracker} device set has no OpenIGTLink server or no device set name")
    return {
        "tracker": tracker,
        "device_set": named.get("Name"),
        "listening_port": int(server.get("ListeningPort", "0")),
        "tools": [source.get("Id") for source in root.iterfind("DataCollection/Device/DataSources/DataSource")],
        "message_types": [message.get("Type") for message in server.iterfind("DefaultClientInfo/MessageTypes/Message")],
        "transforms": [transform.get("Name") for transform in server.iterfind("DefaultClientInfo/TransformNames/Transform")],
    }
