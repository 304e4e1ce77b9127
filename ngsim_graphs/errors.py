"""The exception types for what the pipeline cannot use or cannot write.

Every message is a single line that names the file and, where it applies, the line in it. The
command-line programs print it as `error: ...` and exit with status 1.
"""

from __future__ import annotations

from pathlib import Path


class NgsimError(ValueError):
    """Base of the project's errors. `str(err)` is one line naming the file and place."""

    def __init__(self, path: Path | str | None, message: str, line: int | None = None) -> None:
        where = "" if path is None else f"{path}"
        if line is not None:
            where += f", line {line}"
        super().__init__(f"{where}: {message}" if where else message)
        self.path = path
        self.message = message
        self.line = line

    def __reduce__(self) -> tuple:
        """Pickled by its parts (a build's worker process sends it back whole)."""
        return (type(self), (self.path, self.message, self.line))


class NgsimInputError(NgsimError):
    """Input the pipeline cannot use: a raw file, a build, a run directory or a checkpoint."""


class NgsimOutputError(NgsimError):
    """Output that cannot or must not be written: a full disk, a locked or unsafe `--out`."""
