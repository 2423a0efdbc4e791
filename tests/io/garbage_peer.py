"""A hostile OpenIGTLink peer, run as its own process: every kind of malformed input, one
connection per payload, over and over for a given time. Prints how many payloads it sent.

Usage: python garbage_peer.py PORT SECONDS
"""

from __future__ import annotations

import json
import os
import socket
import sys
import time

import numpy as np

from thrsim.io import igtl


def payloads() -> list[bytes]:
    pose = np.eye(4)
    valid = igtl.encode_message(igtl.Message("TRANSFORM", "ReamerToReference", igtl.pack_transform(pose)))
    bad_crc = bytearray(valid)
    bad_crc[-1] ^= 1
    return [
        os.urandom(512),  # random bytes
        bytes(bad_crc) * 5,  # bad CRC, framing intact
        valid[:30],  # truncated header
        igtl.HEADER.pack(1, b"TRANSFORM", b"X", 0, 1 << 40, 0),  # huge declared body
        igtl.HEADER.pack(9, b"TRANSFORM", b"X", 0, 48, 0) + b"\0" * 48,  # unsupported version
        igtl.encode_message(igtl.Message("NOPE", "X", os.urandom(64))) * 5,  # unknown type
        igtl.encode_message(igtl.Message("TRANSFORM", "ReamerToReference", b"\xff" * 48)),  # NaN content
    ]


def main(port: int, seconds: float) -> None:
    sent = errors = 0
    kinds = payloads()
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        for payload in kinds:
            try:
                with socket.create_connection(("127.0.0.1", port), timeout=1.0) as sock:
                    sock.sendall(payload)
                sent += 1
            except OSError:
                errors += 1
    print(json.dumps({"sent": sent, "errors": errors}), flush=True)


if __name__ == "__main__":
    main(int(sys.argv[1]), float(sys.argv[2]))
