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


def load_toml(path: str | os.PathLike, what: str) -> dict:
    """The TOML document in ``path`` (``what`` it is, for the message); an unreadable file or invalid TOML is a
    :class:`MocapInputError` naming the file."""
    import tomllib

    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except OSError as e:
        raise MocapInputError(path, f"cannot read the {what}: {e.strerror or e}") from None
    except tomllib.TOMLDecodeError as e:
        raise MocapInputError(path, f"not valid TOML: {e}") from None


def silence_opencv() -> None:
    """OpenCV's own log lines (e.g. about a corrupt PNG chunk) would clutter the one-line error messages."""
    import cv2

    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
