"""Errors that reach the user as one line on stderr and exit code 2."""


class ThrsimInputError(Exception):
    """Bad input from the user: a missing file, a malformed mesh, an out-of-range value.

    The CLI prints ``thrsim: error: <message>`` and exits with code 2; never a traceback.
    """


class SimulationError(Exception):
    """A run that cannot go on (NaN, energy explosion); the message names the frame and cause."""


class ThrsimOutputError(OSError):
    """An output that could not be written: a full disk, a file-size limit, an I/O error.

    ``filename`` is the output asked for, not its temporary name: the temporary file is removed
    and a previous file of that name is left as it was. The CLI prints one line and exits with 2.
    """

    def __str__(self) -> str:
        return f"cannot write {self.filename}: {self.strerror}"
