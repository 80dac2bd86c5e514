"""The project's one error type for bad input: it names the file and, where known, the line."""

from __future__ import annotations

import os


class MocapInputError(ValueError):
    """Bad or unreadable input (mocap, calibration, video, sequence folder).

    The message always names the file, and the 1-based line when the problem is at a line.
    """

    def __init__(self, path: str | os.PathLike | None, message: str, line: int | None = None):
        self.path = None if path is None else os.fspath(path)
        self.line = line
        where = self.path if self.path is not None else "<input>"
        if line is not None:
            where = f"{where}:{line}"
        super().__init__(f"{where}: {message}")
