"""The workbench's exceptions and warnings, in one place.

Every refusal of user input is an :class:`InputError` whose message is a single
line naming the file or parameter, the key, what was expected and what came.
The CLI prints that line and exits with status 2; it never shows a traceback
for bad input.
"""

from __future__ import annotations


class InputError(ValueError):
    """Bad input: a file, key, shape or value the workbench cannot accept."""

    def __init__(self, message: str):
        # One line, always: the CLI prints it as is.
        super().__init__(" ".join(str(message).split()))


class DataWarning(UserWarning):
    """Poor but usable data: a constant input, a clipped sensor, a gap in the excitation."""


def describe(value: object) -> str:
    """A short description of what came, for error messages."""
    shape = getattr(value, "shape", None)
    dtype = getattr(value, "dtype", None)
    if shape is not None and dtype is not None:
        return f"array of shape {tuple(shape)} and dtype {dtype}"
    text = repr(value)
    return text if len(text) < 60 else text[:57] + "..."
