"""The kernels of a plugin shipped as machine code beside its code, loaded when first called.

Compiling a numba kernel is mostly numba's own work in Python (reading the bytecode, inferring the
types, writing LLVM IR), LLVM's optimisation of that IR and its making of machine code. A plugin's
bundle (``kernels.bundle`` beside the kernel list its ``lanegraph_kernels`` hook names,
:mod:`.first_run`) holds, for each kernel of the list, what numba's own cache keeps of a compiled
kernel (its type signature, its environment, the descriptor of its function and its library as
object code), made for the x86-64-v3 CPU (numba's ``NUMBA_CPU_NAME=x86-64-v3``, with no feature
of the maker's own CPU beyond it: AVX2, FMA, BMI2), so that it runs on every x86-64 machine that
has those (:func:`cpu_fits`; elsewhere the kernels compile). A run
loads a kernel from it the first time the kernel is called with those types and none is in the
kernel folder (:func:`load`, from :class:`lanegraph.kernels.disk.CheckedCache`'s
``load_overload``, numba's own cache look-up): linking the object code takes milliseconds, nothing
is compiled, and the kernel is saved to the kernel folder as numba saves a compiled one. A run pays
only for the kernels it calls. Types the bundle does not hold are compiled as before.

LLVM's optimisations keep floating-point results exact (lanegraph's kernels are not ``fastmath``: no
multiply-add is fused), so x86-64-v3 machine code computes the same values as code made for the
machine's own CPU; only its speed may differ (no AVX-512: ``benchmarks/bench_kernels.py``).

A bundle is used only where it fits, else the kernels are compiled as before:

- its header (the file's first line, JSON) names the Python, numba and llvmlite versions, the
  machine, the system, the CPU and LLVM's target triple it was made with: all must be this
  process's (the CPU: this one has its features), and numba and llvmlite of the versions lanegraph
  was tested with (:mod:`.compat`);
- each kernel's entry records the digest of its package folder's Python files and of
  :mod:`.decorator` (:func:`package_digest`, also the stamp of the disk cache): an entry made from
  other sources than the installed ones is skipped, as is one whose signature is not the one called;
- ``LANEGRAPH_KERNEL_BUNDLE=0`` turns it off.

A bundle is read only from the folder of the plugin package that names it (never from a path a user
or a graph names; :func:`register` takes the lists :func:`kernel_sets`
found, called by the commands before the first frame, or at the first kernel a process loads once
its plugin manager exists): its entries are pickles, as numba's cache files are. It is made by
``benchmarks/record_kernels.py`` (:func:`write_bundle` in a process with an empty kernel folder,
``NUMBA_CPU_NAME=x86-64-v3`` and ``NUMBA_CPU_FEATURES`` empty)."""

from __future__ import annotations

import functools
import hashlib
import json
import os
import pickle
import platform
import re
import sys
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .compat import dist_version, internals_tested

#: the layout of a bundle file (header line, then the compressed entries; 2: object code)
FORMAT = 2
#: the CPU a bundle's machine code is made for (numba's ``NUMBA_CPU_NAME``, with
#: ``NUMBA_CPU_FEATURES`` empty: the CPU's own features only): x86-64-v3 (AVX2, FMA, BMI2: Intel
#: since 2013, AMD since 2015). The baseline x86-64 (no SSE4.1 ``round``, no POPCNT, no AVX) made
#: some kernels 2-10x slower (``benchmarks/bench_kernels.py``: the v-disparity selection 3 -> 16-33
#: ms, the 2D Hough vote 5-8 -> 31-46 ms)
CPU = "x86-64-v3"
#: the host CPU's features (LLVM's names) that x86-64-v3 code may use: a machine without one of
#: them compiles its kernels instead
CPU_FEATURES = (
    "avx", "avx2", "bmi", "bmi2", "cx16", "f16c", "fma", "lzcnt", "movbe", "popcnt", "sahf",
    "sse3", "sse4.1", "sse4.2", "ssse3", "xsave",
)  # fmt: skip

_LOADED: dict[Path, dict | None] = {}
#: the bundle of each plugin package (its top-level name), from :func:`register`
_REGISTERED: dict[str, Path] = {}
_AUTO = {"done": False}


@functools.cache
def package_digest(folder: str) -> str:
    """SHA-256 of the Python files of ``folder`` (not its subfolders; names and contents, in name
    order) and of :mod:`.decorator` (the kernels' flags): what a compiled kernel of that folder
    depends on (the disk cache's stamp for lanegraph's kernels and a bundle entry's). Read once per
    process."""
    h = hashlib.sha256()
    files = sorted(f for f in os.listdir(folder) if f.endswith(".py")) if os.path.isdir(folder) else []
    for name in files:
        h.update(name.encode() + b"\0")
        with open(os.path.join(folder, name), "rb") as fh:
            h.update(hashlib.sha256(fh.read()).digest())
    with open(Path(__file__).with_name("decorator.py"), "rb") as fh:
        h.update(hashlib.sha256(fh.read()).digest())
    return h.hexdigest()


def enabled() -> bool:
    """False with ``LANEGRAPH_KERNEL_BUNDLE=0`` or ``NUMBA_DISABLE_JIT`` (no kernel is compiled)."""
    return os.environ.get("LANEGRAPH_KERNEL_BUNDLE", "1") != "0" and os.environ.get(
        "NUMBA_DISABLE_JIT", "0"
    ) in ("", "0")


def environment() -> dict:
    """What a bundle must have been made with to be used here (without importing numba)."""
    return {
        "format": FORMAT,
        "python": f"{sys.version_info[0]}.{sys.version_info[1]}",
        "numba": dist_version("numba"),
        "llvmlite": dist_version("llvmlite"),
        "machine": platform.machine(),
        "system": platform.system(),
        "cpu": CPU,
    }


def read_header(path: Path) -> dict | None:
    """The bundle's header (its first line), or None for a file that is missing or unreadable."""
    try:
        with open(path, "rb") as fh:
            header = json.loads(fh.readline())
    except (OSError, ValueError):
        return None
    return header if isinstance(header, dict) else None


def _fits(header: object) -> bool:
    """Whether a bundle with this header (a parsed first line) may be used in this process."""
    return (
        enabled()
        and isinstance(header, dict)
        and all(header.get(k) == v for k, v in environment().items())
        and internals_tested()
        and cpu_fits()
    )


@functools.cache
def cpu_fits() -> bool:
    """Whether this machine's CPU runs :data:`CPU`'s machine code (all of :data:`CPU_FEATURES`)."""
    if platform.machine() not in ("x86_64", "AMD64"):
        return False
    try:
        from llvmlite import binding as ll

        features = ll.get_host_cpu_features()
    except Exception:  # noqa: BLE001 - LLVM cannot tell: the kernels compile
        return False
    return all(features.get(f, False) for f in CPU_FEATURES)


def applies(path: Path) -> bool:
    """Whether the bundle at ``path`` was made for this Python, numba, llvmlite and machine (its
    entries' sources are checked one by one at :func:`install`). Cheap: reads one line."""
    return _fits(read_header(path))


def _entries(path: Path) -> dict | None:
    """The bundle's entries (``{key: (digest, payload)}``), read once per process; None when it does
    not apply here (header, LLVM triple) or cannot be read."""
    if path in _LOADED:
        return _LOADED[path]
    entries = None
    try:
        with open(path, "rb") as fh:
            header = json.loads(fh.readline())
            if _fits(header):
                from llvmlite import binding as ll

                if header.get("triple") == ll.get_process_triple():
                    entries = pickle.loads(zlib.decompress(fh.read()))
    except (OSError, ValueError, zlib.error, pickle.UnpicklingError, EOFError):
        entries = None
    _LOADED[path] = entries if isinstance(entries, dict) else None
    return _LOADED[path]


def keys(path: Path) -> set[str]:
    """The keys (:func:`entry_key`) of the bundle's entries made from the sources installed here
    (their package folder's digest); empty when the bundle does not apply."""
    import importlib.util

    entries = _entries(path) or {}
    held = set()
    for key, item in entries.items():
        module = key.split(":", 1)[0]
        try:
            spec = importlib.util.find_spec(module)
        except (ImportError, ValueError):
            continue
        if spec is not None and spec.origin and item[0] == package_digest(os.path.dirname(spec.origin)):
            held.add(key)
    return held


def read_list(path: Path) -> list[dict]:
    """A kernel list's entries (a plugin's ``kernels.json``; [] for a file that cannot be read)."""
    try:
        entries = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return []
    return [e for e in entries if isinstance(e, dict)] if isinstance(entries, list) else []


def entry_key(entry: dict) -> str:
    """A kernel list entry's key in a bundle: ``module:name:arg|arg|...``."""
    return f"{entry['module']}:{entry['name']}:{'|'.join(str(a) for a in entry['args'])}"


def _digest(dispatcher) -> str:
    return package_digest(os.path.dirname(os.path.abspath(dispatcher.py_func.__code__.co_filename)))


def _registered(package: str) -> Path | None:
    """The bundle registered for ``package``; with none registered yet, those the process's plugin
    manager names, once it exists (a process that runs nodes without a command: a runner's worker,
    ``lanegraph.testing``, an embedding program)."""
    if not _REGISTERED and not _AUTO["done"]:
        plugins = sys.modules.get("lanegraph.plugins")
        pm = getattr(plugins, "_default", None)
        if pm is not None:
            _AUTO["done"] = True
            register(kernel_sets(pm))
    return _REGISTERED.get(package)


@dataclass(frozen=True)
class KernelSet:
    """A plugin's kernel list: the top-level package its entries may name, the list file, and its
    entries (those of other packages left out)."""

    package: str
    list_path: Path
    entries: tuple[dict, ...]

    @property
    def bundle_path(self) -> Path:
        """The machine code of the list's kernels, beside it."""
        return self.list_path.with_suffix(".bundle")


def kernel_sets(pm: Any = None) -> list[KernelSet]:
    """The kernel lists the plugins of ``pm`` (the process's plugin manager by default) name through
    ``lanegraph_kernels``, each read from inside its plugin's package folder only; a plugin whose
    hook raises or names a file elsewhere is passed over (its kernels compile when called)."""
    if pm is None:
        from ..plugins import get_plugin_manager

        pm = get_plugin_manager()
    hook = getattr(pm.hook, "lanegraph_kernels", None)
    sets = []
    for impl in reversed(hook.get_hookimpls() if hook is not None else []):
        name = getattr(impl.plugin, "__name__", None) or type(impl.plugin).__module__
        package = str(name).split(".")[0]
        module = sys.modules.get(package)
        home = getattr(module, "__file__", None)
        try:
            named = impl.function()
        except Exception:  # noqa: BLE001 - a hint only: the plugin's kernels compile when called
            continue
        if named is None or home is None:
            continue
        path = Path(named).resolve()
        if Path(home).resolve().parent not in path.parents:
            continue  # beside the plugin's code only
        entries = tuple(e for e in read_list(path) if str(e.get("module", "")).split(".")[0] == package)
        sets.append(KernelSet(package, path, entries))
    return sets


def register(sets) -> None:
    """Use these kernel lists' bundles (:class:`KernelSet`: a package and
    its list, read from inside the plugin's folder) for their packages' kernels from now on."""
    for s in sets:
        if s.entries:
            _REGISTERED[s.package] = s.bundle_path


def _payload(py_func, sig: tuple, entries: dict | None, key: str | None):
    """The unpickled entry ``key`` of a bundle for ``py_func`` called with ``sig``; None when it is
    missing, made from other sources or for another signature."""
    item = entries.get(key) if entries and key else None
    if item is None:
        return None
    if item[0] != package_digest(os.path.dirname(os.path.abspath(py_func.__code__.co_filename))):
        return None
    payload = pickle.loads(item[1])
    if tuple(payload[3].args) != tuple(sig):  # its signature: checked before any machine code is linked
        return None
    return payload


def _sig_key(py_func, sig: tuple) -> str | None:
    args = [encode_type(t) for t in sig]
    if None in args:
        return None
    return f"{py_func.__module__}:{py_func.__qualname__}:{'|'.join(args)}"


def load(py_func, sig: tuple, target_context):
    """The kernel ``py_func`` for the argument types ``sig`` from its plugin's registered bundle
    (:func:`register`), as numba's cache gives a kernel: ``(CompileResult, payload)``, the payload
    being what numba's cache keeps of it (to save it to the kernel folder); None when no registered
    bundle applies or holds it (it is then compiled). Called under numba's compiler lock."""
    if not enabled():
        return None
    path = _registered(str(py_func.__module__).split(".")[0])
    if path is None:
        return None
    payload = _payload(py_func, sig, _entries(path), _sig_key(py_func, sig))
    if payload is None:
        return None
    from numba.core.compiler import CompileResult

    return CompileResult._rebuild(target_context, *payload), payload


def install(dispatcher, sig: tuple, entry: dict, path: Path) -> bool:
    """Give ``dispatcher`` its overload for ``sig`` (the kernel list's ``entry``) from the bundle at
    ``path`` ahead of its first call, registered as numba registers a kernel from its cache and
    saved to the kernel folder. False (nothing done) when the bundle does not apply or has no entry
    for it from these sources; the caller then compiles it."""
    if not enabled():
        return False
    from numba.core.compiler import CompileResult
    from numba.core.compiler_lock import global_compiler_lock

    with global_compiler_lock:
        if sig in dispatcher.overloads:
            return True
        payload = _payload(dispatcher.py_func, sig, _entries(path), entry_key(entry))
        if payload is None:
            return False
        dispatcher.targetctx.refresh()  # numba's runtime (NRT) and registries, as its cache's load does
        cres = CompileResult._rebuild(dispatcher.targetctx, *payload)
        dispatcher.targetctx.insert_user_function(cres.entry_point, cres.fndesc, [cres.library])
        dispatcher.add_overload(cres)
        save = getattr(dispatcher._cache, "save_payload", None)  # a NullCache without the disk cache
        if save is not None:
            save(sig, dispatcher.targetctx.codegen(), payload)
    return True


def write_bundle(entries: list[dict], out: Path) -> int:
    """Compile each kernel list entry in this process and write the bundle to ``out``; returns how
    many entries it holds. The process's kernel folder must be empty (a kernel numba loads from its
    cache is not compiled here) and numba's CPU :data:`CPU` (``NUMBA_CPU_NAME=x86-64-v3`` and an
    empty ``NUMBA_CPU_FEATURES`` set before numba is imported): run it in a fresh process
    (``record_kernels.py`` does)."""
    import importlib

    if not internals_tested():
        raise RuntimeError("a bundle is made only with the numba and llvmlite lanegraph was tested with")
    from llvmlite import binding as ll
    from numba.core import config, serialize

    if str(config.CPU_NAME).lower() != CPU or config.CPU_FEATURES != "":
        raise RuntimeError(
            f"a bundle is made for one CPU: set NUMBA_CPU_NAME={CPU} and NUMBA_CPU_FEATURES= (empty) "
            "before numba loads"
        )
    kept = {}
    for entry in entries:
        kernel = getattr(importlib.import_module(str(entry["module"])), str(entry["name"]))
        sig = tuple(decode_type(str(a)) for a in entry["args"])
        kernel.compile(sig)
        cres = kernel.overloads.get(sig)
        if cres is None or kernel.stats.cache_hits.get(sig, 0):
            raise RuntimeError(f"{entry_key(entry)}: not compiled in this process (empty the kernel folder)")
        reduced = cres._reduce()  # as numba's cache keeps it (object code), with the type annotation
        # (a text for numba's ``inspect_types``, with the addresses of this process's objects in it)
        # replaced by a note: the bundle is the same bytes for the same sources
        note = f"{entry_key(entry)}: from lanegraph's kernel bundle (no type annotation kept)"
        payload = (*reduced[:6], note, *reduced[7:])
        kept[entry_key(entry)] = (_digest(kernel), serialize.dumps(payload))
    header = {**environment(), "triple": ll.get_process_triple()}
    body = zlib.compress(pickle.dumps(kept, protocol=pickle.HIGHEST_PROTOCOL), 9)
    out.write_bytes(json.dumps(header, sort_keys=True).encode() + b"\n" + body)
    return len(kept)


_ARRAY = re.compile(r"array\((\w+), (\d+), ([CFA])(, readonly)?\)")


def encode_type(t) -> str | None:
    """A numba argument type as the kernel list writes it (``float64``, ``array(uint8, 2, C)``,
    ``array(int64, 1, C, readonly)``); None for a type it does not write (literals, tuples, ...)."""
    from numba.core import types

    if isinstance(t, types.Literal):
        return None
    if isinstance(t, types.Array) and isinstance(t.dtype, (types.Integer, types.Float, types.Boolean)):
        return f"array({t.dtype}, {t.ndim}, {t.layout}{'' if t.mutable else ', readonly'})"
    if isinstance(t, (types.Integer, types.Float, types.Boolean)):
        return str(t)
    return None


def decode_type(text: str):
    """The numba type :func:`encode_type` wrote (ValueError, TypeError for another text)."""
    import numba
    import numpy as np
    from numba.core import types

    m = _ARRAY.fullmatch(text)
    if m:
        return types.Array(numba.from_dtype(np.dtype(m[1])), int(m[2]), m[3], readonly=bool(m[4]))
    if not re.fullmatch(r"(bool|u?int(8|16|32|64)|float(32|64))", text):
        raise ValueError(f"not a kernel argument type: {text!r}")
    return numba.from_dtype(np.dtype(text))


def _main(argv: list[str]) -> int:
    if not argv or len(argv) % 2:
        print("usage: python -m lanegraph.kernels bundle LIST OUT [LIST OUT ...] (empty kernel folder)")
        return 2
    for k in range(0, len(argv), 2):
        n = write_bundle(read_list(Path(argv[k])), Path(argv[k + 1]))
        print(f"{n} kernels -> {argv[k + 1]}")
    return 0


__all__ = [
    "applies",
    "cpu_fits",
    "decode_type",
    "enabled",
    "encode_type",
    "environment",
    "install",
    "keys",
    "load",
    "package_digest",
    "read_header",
    "read_list",
    "register",
    "write_bundle",
]
