"""pyigtl (0.3.4) has no SENSOR message: this adds one, written from the OpenIGTLink SENSOR
specification (u8 array length, u8 status, u64 unit, float64 values, big-endian) on pyigtl's own
message base, so that pyigtl's framing, header parsing and client read what the trainer writes."""

from __future__ import annotations

import struct

import pyigtl
from pyigtl import messages


class SensorMessage(pyigtl.MessageBase):
    def __init__(self, values=(), unit: int = 0, timestamp=None, device_name=None):
        super().__init__(timestamp=timestamp, device_name=device_name)
        self._message_type = "SENSOR"
        self.values, self.unit, self.status = list(values), unit, 0
        self._valid_message = True

    def _pack_content(self) -> bytes:
        return struct.pack(f"> B B Q {len(self.values)}d", len(self.values), self.status, self.unit, *self.values)

    def _unpack_content(self, content: bytes) -> None:
        count, self.status, self.unit = struct.unpack("> B B Q", content[:10])
        self.values = list(struct.unpack(f"> {count}d", content[10 : 10 + 8 * count]))


def register() -> None:
    """pyigtl's clients (in this process) decode SENSOR messages from now on."""
    messages.message_type_to_class_constructor["SENSOR"] = SensorMessage
