"""lanegraph's numba kernels: the decorator plugins use, where compiled kernels are kept, and the
first run of an installation.

- :mod:`.decorator`: :func:`lanegraph.jit` and :data:`lanegraph.prange` (numba's, with the project's
  flags and its checked disk cache); the only module here that imports numba at load, with
  :mod:`.disk`.
- :mod:`.folder`: the kernel folder (the user's own, never the results cache) and the results
  cache's root; no numba.
- :mod:`.disk`: the kernel folder's files, signed by lanegraph and checked before numba reads them.
- :mod:`.first_run`: the plugins' kernel lists (the ``lanegraph_kernels`` hook), the first run's
  notice and the kernels it compiles ahead where no bundle holds them; :mod:`.bundle`: a plugin's
  kernels as machine code for x86-64-v3 CPUs, each loaded when first called (by
  :mod:`.disk`'s cache look-up).
- :mod:`.compat`: the numba and llvmlite versions whose internals the above were tested with.

The run service calls :func:`first_run_notice` before it loads anything and :func:`compile_share`
once the graph is read, before the first frame (it registers the plugins' bundles).
"""

from __future__ import annotations

from .first_run import compile_share, first_run_notice, kernel_sets

__all__ = ["compile_share", "first_run_notice", "kernel_sets"]
