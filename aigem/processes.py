"""What a fit would leave running beside its own process: ended with the fit, so that a command
ends with its last line.

What would outlive its work, to be stopped at the interpreter's exit by PyTorch's exit handlers,
which wait:

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
"""

from __future__ import annotations

from torch.utils.data import DataLoader


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
