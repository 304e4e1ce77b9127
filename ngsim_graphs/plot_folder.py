"""A folder that a command draws its pictures into (`ngsim-graphs stats --plots DIR`, `aigem
evaluate --plots DIR`): the one rule for which of its files are ours to replace.

    DIR/plots.json   the pictures that this project's commands wrote into DIR, by name

DIR is created. A file of a command's picture names that plots.json does not list (a picture,
or anything, of the user's: a heading.png of their own) is never replaced: the call stops with
one error naming it before anything is written. Every picture is drawn before the first is
written; each is written under a temporary name and renamed (partial_files.write_atomic), and
plots.json lists it before it lands, so a kill leaves nothing of ours unlisted. A picture that a
command wrote before and does not draw now is removed, so that DIR never mixes two calls of a
command; every other file, and another command's pictures, stay.
"""

from __future__ import annotations

import json
import os
from collections.abc import Collection, Mapping
from pathlib import Path

from ngsim_graphs.errors import NgsimOutputError
from ngsim_graphs.partial_files import write_atomic

OWNED = "plots.json"


def _listed(folder: Path) -> set[str]:
    """The pictures that plots.json in `folder` lists as ours (none without the file)."""
    path = folder / OWNED
    if not os.path.lexists(path):
        return set()
    try:
        listed = json.loads(path.read_text())["pictures"]
        if not isinstance(listed, list) or not all(isinstance(n, str) for n in listed):
            raise TypeError
    except (OSError, ValueError, KeyError, TypeError):
        raise NgsimOutputError(
            path,
            "is not the list of plots of ngsim-graphs or aigem; move it or choose another "
            "--plots folder",
        ) from None
    return set(listed)


def claim_plot_folder(folder: Path, names: Collection[str], writer: str) -> set[str]:
    """Create `folder` and return which of the picture `names` it holds as ours; refuses (an
    NgsimOutputError, before anything is written) a picture of those names that is not ours,
    `writer` (e.g. "aigem evaluate --plots") saying whose they would be."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise NgsimOutputError(folder, f"cannot write plots: {err.strerror or err}") from None
    listed = _listed(folder)
    for name in names:
        if os.path.lexists(folder / name) and name not in listed:  # a link of the user's too
            raise NgsimOutputError(
                folder / name,
                f"exists and was not written by `{writer}`; move it or choose another --plots "
                "folder",
            )
    return listed & set(names)


def _list(folder: Path, names: set[str], writer: str) -> None:
    document = {"last_written_by": writer, "pictures": sorted(names)}
    write_atomic(folder / OWNED, (json.dumps(document, indent=1) + "\n").encode())


def land_plots(
    folder: Path, pictures: Mapping[str, bytes], owned: set[str], writer: str
) -> list[Path]:
    """Write `pictures` (file name -> PNG bytes) into `folder`, which claim_plot_folder claimed
    and found holding `owned`; remove the pictures of `owned` not among them. Returns the paths
    written, in the order of `pictures`."""
    others = _listed(folder) - owned  # another command's pictures: left as they are
    _list(folder, others | owned | set(pictures), writer)
    written = []
    for name, data in pictures.items():
        write_atomic(folder / name, data)
        written.append(folder / name)
    for stale in sorted(owned - set(pictures)):
        (folder / stale).unlink(missing_ok=True)
    _list(folder, others | set(pictures), writer)
    return written
