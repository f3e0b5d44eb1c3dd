"""The one exception type that the command line turns into a one-line message."""

from __future__ import annotations

from pathlib import Path


class PipemapError(Exception):
    """A problem with the user's input, reported as one line naming where it is.

    `where` is the file (and, for structured files, the key) the problem was found in.
    """

    def __init__(self, message: str, where: str | Path | None = None, key: str | None = None):
        self.message = message
        self.where = str(where) if where is not None else None
        self.key = key
        super().__init__(self.line())

    def line(self) -> str:
        place = self.where or ""
        if self.key:
            place = f"{place}: {self.key}" if place else self.key
        return f"{place}: {self.message}" if place else self.message
