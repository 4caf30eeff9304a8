"""The one place numba flags come from.

Use :func:`jit` for every kernel. Kernels are cached on disk in a *user* cache directory shared by
every ``$LANEGRAPH_CACHE_DIR`` (``~/.cache/lanegraph/kernels``, or ``$LANEGRAPH_KERNEL_CACHE``;
``NUMBA_CACHE_DIR`` wins when set; :mod:`lanegraph.kernel_cache`), so only the first run on a
machine pays the compilation, also when the install directory is read-only.
``LANEGRAPH_NUMBA_CACHE=0`` turns the disk cache off; ``NUMBA_DISABLE_JIT=1`` turns every kernel
into plain Python (for coverage and debugging).

numba keeps a cached kernel while its own source file is unchanged, but a kernel holds the machine
code of every function it calls, compiled in: after an edit of a helper in another file (a shared
quickselect, say) the callers would go on running the old helper from the cache. A kernel made by
:func:`jit` is therefore kept only while *every* Python file of its package folder is unchanged
(and this file, whose flags shape the code): :class:`_PackageLocator`. Editing one file of
``lanegraph_lanes`` compiles that package's kernels again on the next run; a kernel that calls
into another package is not covered (the built-in plugins' kernels call none).

The parallel kernels' worker threads (numba's OpenMP layer) sleep as soon as a kernel ends
(``OMP_WAIT_POLICY=PASSIVE``, set unless the environment already sets it, before the OpenMP
runtime starts): spinning, they took a core from the next node's OpenCV threads and from the
thread that reads the next frame. On the 2-core reference machine (``bench_pipeline.py``, two
runs each, default -> passive): after disparity 10.9-11.1 -> 10.4-10.5 ms (paper.yaml), ESLT's
spikes of 4-8 ms on a frame in eight gone, end to end 10.3 -> 11.2-12.0 frames/s (paper.yaml) and
33 -> 34-38 frames/s (half_res.yaml). Set ``OMP_WAIT_POLICY=ACTIVE`` to keep the threads spinning.

numba's type inference resolves each call of a built-in function or operator (``a + b``, ``x[i]``,
``min``, ``np.empty``) by trying that function's typing templates in turn, and does it again at
every pass over the function's constraints, for every call site: over 9,500 resolutions on a first
run of the default graph, all but about 380 of them repeats of one already made (the same function
and argument types). While lanegraph compiles its kernel list, each successful resolution is
kept (:func:`lanegraph.kernel_cache.kept_call_types`), so a repeat costs a dictionary look-up: the
same signatures, hence the same machine code, for 1.2-1.5 s less CPU on the first run (issue 32;
``LANEGRAPH_NUMBA_CALL_MEMO=0`` turns it off). Outside those compilations numba's own method is in
place: a user's own numba code is compiled as numba does it.
"""

from __future__ import annotations

import os

from .kernel_bundle import package_digest  # noqa: F401 - a kernel's sources, for numba's cache stamp
from .kernel_cache import cache_root, kernel_cache_dir  # noqa: F401 - cache_root: lanegraph.cache uses it

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # read when the OpenMP runtime loads: see above

# numba's error texts without colorama's escapes (its default theme has no colours anyway): numba
# formats such a text for each value it tries to type and cannot, about 8,000 times on a first run,
# and colorama's wrapping of the streams each time cost 0.3-0.5 s of CPU for the default run's
# kernels (read when numba loads)
os.environ.setdefault("NUMBA_DISABLE_ERROR_MESSAGE_HIGHLIGHTING", "1")

if not os.environ.get("NUMBA_CACHE_DIR"):  # shared by every LANEGRAPH_CACHE_DIR: see lanegraph.kernel_cache
    os.environ["NUMBA_CACHE_DIR"] = str(kernel_cache_dir())

import numba  # noqa: E402 - after NUMBA_CACHE_DIR is set

if not numba.config.CACHE_DIR:
    numba.config.CACHE_DIR = os.environ["NUMBA_CACHE_DIR"]

from numba.core import caching as _caching  # noqa: E402


class _PackageLocator(_caching.UserProvidedCacheLocator):
    """numba's locator of the cache folder (``numba.config.CACHE_DIR``) for the kernels made by
    :func:`jit`, whose source stamp also covers the other files of the kernel's package
    (:func:`package_digest`): see the module's text."""

    def get_source_stamp(self):
        own = super().get_source_stamp()
        return (own, package_digest(os.path.dirname(os.path.abspath(self._py_file))))

    @classmethod
    def from_function(cls, py_func, py_file):
        if not getattr(py_func, "_lanegraph_kernel", False):
            return None  # not lanegraph's: numba's own locators
        return super().from_function(py_func, py_file)


if _PackageLocator not in _caching.CacheImpl._locator_classes:
    _caching.CacheImpl._locator_classes.insert(0, _PackageLocator)


def _marked(func):
    """``func`` marked as a lanegraph kernel (:class:`_PackageLocator` keeps its cache)."""
    func._lanegraph_kernel = True
    return func


#: flags shared by every lanegraph kernel
JIT_OPTIONS = {
    "nopython": True,
    "cache": os.environ.get("LANEGRAPH_NUMBA_CACHE", "1") != "0",
    "nogil": True,
    "fastmath": False,
    # no C-callable wrapper beside each function (only a function passed as a first-class value
    # would use it; lanegraph passes none): one function less to lower, optimise and turn into
    # machine code for every kernel and helper, and for every one of numba's own functions they call
    "no_cfunc_wrapper": True,
}


def jit(*args, **overrides):
    """``numba.jit`` with the project's flags; use as ``@jit`` or ``@jit(parallel=True)``."""
    opts = {**JIT_OPTIONS, **overrides}
    if args and callable(args[0]):
        return numba.jit(**opts)(_marked(args[0]))
    decorate = numba.jit(*args, **opts)
    return lambda func: decorate(_marked(func))


prange = numba.prange
