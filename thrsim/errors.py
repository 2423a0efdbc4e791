"""Errors that reach the user as one line on stderr and exit code 2."""


class ThrsimInputError(Exception):
    """Bad input from the user: a missing file, a malformed mesh, an out-of-range value.

    The CLI prints ``thrsim: error: <message>`` and exits with code 2; never a traceback.
    """


class SimulationError(Exception):
    """A run that cannot go on (NaN, energy explosion); the message names the frame and cause."""
