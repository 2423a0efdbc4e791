"""Trainer sessions on disk: every input with its time and each mode's outputs, in one HDF5 file."""

from thrsim.session.file import (
    FORMAT,
    FORMAT_VERSION,
    InputLog,
    SessionFile,
    read_session,
    write_session,
)

__all__ = ["FORMAT", "FORMAT_VERSION", "InputLog", "SessionFile", "read_session", "write_session"]
