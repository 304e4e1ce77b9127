"""What a fit would leave running beside its own process: ended with the fit, so that a command
ends with its last line.

Two kinds would outlive their work, to be stopped at the interpreter's exit by PyTorch's exit
handlers, which wait:

- A DataLoader with persistent workers keeps its worker processes (and, pinning memory on CUDA,
  a pin-memory thread) until its iterator is garbage-collected. After an error, an interrupt or a
  SIGTERM, the traceback holds the training loop's frames and with them the loaders, for as long
  as it is kept: in `aigem` until Python handles the exit, after the last line (a worker then
  sometimes printed a ConnectionResetError traceback: 4 of 11 fits stopped by SIGTERM, on the
  CPU), by a caller that keeps the exception for longer. Loaders alive at the interpreter's exit
  (a kept exception, a reference cycle) are left to PyTorch's exit handlers, which, for loaders
  that pin memory, in older releases join each worker with a 5 s timeout that the worker, never
  told to stop, runs out (pytorch/pytorch#81794; the handler that pytorch/pytorch#176607
  replaced): 2 minutes for the 12 workers of a train and of a validation loader on a 16-core GPU
  machine. `release_workers` ends them as the fit ends, on every path.
- torch.compile's Inductor compiles Triton kernels (CUDA) in a pool of worker processes, a
  sidecar process and one worker per core (up to 32), kept until the interpreter exits, where
  its shutdown waits for the sidecar for up to 300 s: pytorch/pytorch#162199 reports that wait
  after a cold start (a fresh kernel cache, as on a machine just lent). `compile_in_process`
  compiles in this process instead: no pool to wait for.

And one kind would outlive the fit itself: a DataLoader worker whose fit is killed outright
(kill -9, the out-of-memory killer) notices only at its next status check, every 5 s (PyTorch's
MP_STATUS_CHECK_INTERVAL), and went on loading batches for 6 s. `EndWithParent`, each loader's
`worker_init_fn`, asks Linux to kill the worker the moment its parent ends
(prctl(PR_SET_PDEATHSIG, SIGKILL), prctl(2)).
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys

from torch.utils.data import DataLoader

COMPILE_THREADS = "TORCHINDUCTOR_COMPILE_THREADS"  # Inductor's setting of compile_threads
PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


class EndWithParent:
    """A DataLoader's `worker_init_fn` that ends each worker with the process that made the
    loader: on Linux the kernel sends the worker SIGKILL when its parent ends, however it ends
    (prctl(PR_SET_PDEATHSIG), the documented mechanism; a worker holds nothing of its own to
    clean up: its batches are the parent's). The kernel sends it when the thread that started
    the worker ends: the loaders of fit and of load_split are iterated by the main thread. A
    parent that ended before the worker asked is caught by its pid. Elsewhere PyTorch's own
    check, within 5 s, is left to end the worker. Picklable: a spawned worker receives it.
    """

    def __init__(self) -> None:
        self.parent_pid = os.getpid()

    def __call__(self, worker_id: int) -> None:
        if not sys.platform.startswith("linux"):
            return
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), "prctl(PR_SET_PDEATHSIG) failed")
        if os.getppid() != self.parent_pid:  # the parent ended before the request
            os._exit(1)


def release_workers(*loaders: DataLoader) -> None:
    """End the worker processes of `loaders` now (and their pin-memory threads), where they have
    any; a loader iterated again starts new ones.

    PyTorch has no public call for this: a loader's persistent workers end when its iterator is
    garbage-collected, by the iterator's `_shutdown_workers`, which is what this calls (as PyTorch
    Lightning's `_shutdown_workers_and_reset_iterator` does). It tells each worker to stop and
    joins it, at once for a worker waiting for work. Without that method (another PyTorch), the
    loader at least lets go of its iterator.
    """
    for loader in loaders:
        iterator = getattr(loader, "_iterator", None)
        shutdown = getattr(iterator, "_shutdown_workers", None)
        if shutdown is not None:
            shutdown()
        loader._iterator = None


def compile_in_process() -> None:
    """Have torch.compile's Inductor compile in this process, in no pool of worker processes
    (its `compile_threads` 1: the setting that PyTorch's own messages give for compiling "in the
    main process"), unless TORCHINDUCTOR_COMPILE_THREADS says otherwise. Process-wide, and read
    when a compilation starts: call it before the first call of a compiled function. The price
    is a slower first compilation on a cold kernel cache (the kernels one after the other); a
    warm cache compiles nothing."""
    if COMPILE_THREADS in os.environ:  # the user's choice, exit wait included
        return
    import torch._inductor.config  # loaded here: only a fit that compiles needs Inductor

    torch._inductor.config.compile_threads = 1
