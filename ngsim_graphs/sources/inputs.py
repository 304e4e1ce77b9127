"""The paths a build is given, as every source walks them: a named file, or a folder searched."""

from __future__ import annotations

from pathlib import Path

from ngsim_graphs.errors import NgsimInputError
from ngsim_graphs.sources.archives import archive_kind


def files_in(path: Path, suffixes: tuple[str, ...]) -> list[Path] | None:
    """None for a named file; for a folder, every file under it (recursively) whose suffix is
    one of `suffixes` (lower case), in path order, but for compressed ones (a .txt gzip'd under
    its own name): a build reads those unpacked (`archives`). Raises NgsimInputError for a path
    that does not exist."""
    if not path.exists():
        raise NgsimInputError(path, "no such file or directory")
    if path.is_file():
        return None
    named = (p for p in path.rglob("*") if p.is_file() and p.suffix.lower() in suffixes)
    return sorted(p for p in named if archive_kind(p) is None)
