"""The installed programs' entry points (pyproject.toml): a Ctrl-C while a program loads is one
line, not the traceback of whichever import it stopped.

Loading `ngsim-graphs` imports Polars, NumPy and the pipeline, half a second and more, and
`aigem` as much. Ctrl-C is held off while they load and answered once they have: Polars' native
start-up turns an interrupt that reaches it into a panic (`PanicException`, not a
KeyboardInterrupt), which no handler could tell from a bug. The commands handle an interrupt
themselves once they run (`console.exit_on_interrupt`; `aigem fit` and `evaluate` also while they
load PyTorch, seconds).
"""

from __future__ import annotations

import importlib
import signal
import sys
from collections.abc import Callable


def _loaded(module: str) -> Callable[[], None]:
    """`module`'s `main`, imported with Ctrl-C held off; exit 130 with one line if one came."""
    came: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, _frame: came.append(signum))
    try:
        main = importlib.import_module(module).main
    finally:
        signal.signal(signal.SIGINT, previous)
    if came:
        sys.stderr.write("interrupted; nothing written\n")
        sys.exit(130)
    return main


def ngsim_graphs() -> None:
    """`ngsim-graphs`: its commands, once loaded."""
    _loaded("ngsim_cli.ngsim")()


def aigem() -> None:
    """`aigem`: its commands, once loaded."""
    _loaded("ngsim_cli.aigem")()
