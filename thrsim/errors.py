"""Errors that reach the user as one line on stderr and exit code 2.

The library's errors speak of values and setting names (``frames``, ``igtl_allow``), never of
command-line flags: a :class:`ThrsimInputError` names the setting it blames, and the CLI, which
knows the flags, words it with the flag instead (:func:`thrsim.cli.output.user_message`).
"""


class ThrsimInputError(Exception):
    """Bad input from the user: a missing file, a malformed mesh, an out-of-range value.

    ``setting`` names the setting the message is about (it leads the message, ``"frames: must be at
    least 1"``); ``mentions`` names further settings the message's advice names, each written in
    parentheses (``"(igtl_host)"``). The CLI prints ``thrsim: error: <message>``, these names as its
    flags, and exits with code 2; never a traceback.
    """

    def __init__(self, message: str, setting: str | None = None, mentions: tuple[str, ...] = ()):
        super().__init__(message, setting, mentions)
        self.message, self.setting, self.mentions = message, setting, mentions

    def __str__(self) -> str:
        return self.message if self.setting is None else f"{self.setting}: {self.message}"


class SimulationError(Exception):
    """A run that cannot go on (NaN, energy explosion); the message names the frame and cause."""


class ThrsimOutputError(OSError):
    """An output that could not be written: a full disk, a file-size limit, an I/O error.

    ``filename`` is the output asked for, not its temporary name: the temporary file is removed
    and a previous file of that name is left as it was. The CLI prints one line and exits with 2.
    """

    def __str__(self) -> str:
        return f"cannot write {self.filename}: {self.strerror}"
