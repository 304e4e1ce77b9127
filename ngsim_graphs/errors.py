"""The one exception type for bad input: its message is a single line that names the file."""

from __future__ import annotations

from pathlib import Path


class NgsimInputError(ValueError):
    """Raised for input the pipeline cannot use. `str(err)` is one line naming the file and place."""

    def __init__(self, path: Path | str | None, message: str, line: int | None = None) -> None:
        where = "" if path is None else f"{path}"
        if line is not None:
            where += f", line {line}"
        super().__init__(f"{where}: {message}" if where else message)
        self.path = path
        self.line = line
