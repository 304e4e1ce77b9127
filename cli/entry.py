"""The installed programs' entry points (pyproject.toml): a Ctrl-C while a program loads is one
line, not the traceback of whichever import it stopped.

Loading `ngsim-graphs` imports Polars, NumPy and the pipeline, half a second and more, and
`aigem` as much; the commands handle an interrupt themselves once they run
(`console.exit_on_interrupt`; `aigem fit` and `evaluate` also while they load PyTorch, seconds).
"""

from __future__ import annotations

import sys


def ngsim_graphs() -> None:
    """`ngsim-graphs`: its commands, once loaded."""
    try:
        from ngsim_cli.ngsim import main
    except KeyboardInterrupt:
        sys.stderr.write("interrupted; nothing written\n")
        sys.exit(130)
    main()


def aigem() -> None:
    """`aigem`: its commands, once loaded."""
    try:
        from ngsim_cli.aigem import main
    except KeyboardInterrupt:
        sys.stderr.write("interrupted; nothing written\n")
        sys.exit(130)
    main()
