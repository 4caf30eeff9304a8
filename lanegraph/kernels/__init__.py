"""lanegraph's numba kernels: the decorator plugins use (:mod:`.decorator`, :func:`lanegraph.jit`),
where compiled kernels are kept (:mod:`.folder`, :mod:`.disk`), the first run of an installation
(:mod:`.first_run`, :mod:`.bundle`) and the numba versions they were tested with (:mod:`.compat`);
each module says its part, docs/architecture.md the whole. The run service calls
:func:`first_run_notice` before it loads anything and :func:`compile_share` once the graph is read.
"""

from __future__ import annotations

from .first_run import compile_share, first_run_notice, kernel_sets

__all__ = ["compile_share", "first_run_notice", "kernel_sets"]
