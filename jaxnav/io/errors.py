"""The one exception every jaxnav reader raises on bad input.

``InputError`` names the file, the place in it (line, record or epoch) and what was expected,
so a user can open the file at the right spot. It subclasses ``ValueError`` so generic callers
that catch ``ValueError`` keep working.

Every reader returns times on the GPS time scale of ``jaxnav/core/gpstime.py``.
"""

from __future__ import annotations

from os import PathLike


class InputError(ValueError):
    """Bad input file: says which file, where (line / record / epoch) and what was expected."""

    def __init__(
        self,
        message: str,
        *,
        file: str | PathLike | None = None,
        line: int | None = None,
        record: int | None = None,
        epoch: object | None = None,
        expected: str | None = None,
    ):
        self.file = None if file is None else str(file)
        self.line = line
        self.record = record
        self.epoch = epoch
        self.expected = expected
        self.message = message
        where = []
        if self.file is not None:
            where.append(self.file)
        if line is not None:
            where.append(f"line {line}")
        if record is not None:
            where.append(f"record {record}")
        if epoch is not None:
            where.append(f"epoch {epoch}")
        text = ", ".join(where)
        text = f"{text}: {message}" if text else message
        if expected:
            text += f" (expected {expected})"
        super().__init__(text)
