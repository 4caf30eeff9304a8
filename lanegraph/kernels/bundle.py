"""The kernels of a plugin shipped as LLVM bitcode beside its code: a first run on a machine turns
them into machine code instead of compiling them from Python.

Compiling a numba kernel is mostly numba's own work in Python (reading the bytecode, inferring the
types, writing LLVM IR) and LLVM's optimisation of that IR; only the last step, making machine code of
the optimised IR, belongs to the machine. A plugin's bundle (``kernels.bundle`` beside the kernel
list its ``lanegraph_kernels`` hook names, :mod:`.first_run`) holds, for each kernel of the list,
what numba's own cache keeps of a compiled kernel (its type signature, its environment, the
descriptor of its function) with the library as the optimised *bitcode* of its module (every
function it calls linked in; taken as LLVM's code generator gets it) instead of machine code.
:func:`install` makes machine code of it for this machine (numba's ``_finalize_final_module``),
registers the kernel's overload with its dispatcher, as numba does with a kernel from its cache,
and saves it to the kernel folder: the next runs load it from there like any compiled kernel. The
default run's kernels take about a sixth of their compilation's CPU this way
(``benchmarks/bench_first_run.py``).

LLVM's optimisations keep floating-point results exact (lanegraph's kernels are not ``fastmath``), so
machine code made for another x86-64 CPU than the one the bundle was made on computes the same
values; only its speed may differ a little (vector widths chosen for the maker's CPU).

A bundle is used only where it fits, else the kernels are compiled as before:

- its header (the file's first line, JSON) names the Python, numba and llvmlite versions, the
  machine, the system and LLVM's target triple it was made with: all must be this process's, and
  numba and llvmlite of the versions lanegraph was tested with (:mod:`.compat`);
- each kernel's entry records the digest of its package folder's Python files and of
  :mod:`.decorator` (:func:`package_digest`, also the stamp of the disk cache): an entry made from
  other sources than the installed ones is skipped;
- ``LANEGRAPH_KERNEL_BUNDLE=0`` turns it off.

A bundle is read only from the folder of the plugin package that names it (never from a path a user
or a graph names): its entries are pickles, as numba's cache files are. It is made by
``benchmarks/record_kernels.py`` (:func:`write_bundle` in a process with an empty kernel folder)."""

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
from importlib import metadata
from pathlib import Path

from .compat import internals_tested

#: the layout of a bundle file (header line, then the compressed entries)
FORMAT = 1

_LOADED: dict[Path, dict | None] = {}


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


def _version(dist: str) -> str:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:  # pragma: no cover - numba and llvmlite are dependencies
        return "?"


def environment() -> dict:
    """What a bundle must have been made with to be used here (without importing numba)."""
    return {
        "format": FORMAT,
        "python": f"{sys.version_info[0]}.{sys.version_info[1]}",
        "numba": _version("numba"),
        "llvmlite": _version("llvmlite"),
        "machine": platform.machine(),
        "system": platform.system(),
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
    )


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


def install(dispatcher, sig: tuple, entry: dict, path: Path) -> bool:
    """Give ``dispatcher`` its overload for ``sig`` (the kernel list's ``entry``) from the bundle:
    machine code made here of the shipped bitcode, registered as numba registers a kernel from its
    cache, then saved to the kernel folder. False (nothing done) when the bundle does not apply or
    has no entry for it from these sources; the caller then compiles it."""
    if not enabled():
        return False
    entries = _entries(path)
    item = entries.get(entry_key(entry)) if entries else None
    if item is None or item[0] != _digest(dispatcher):
        return False
    from numba.core.compiler_lock import global_compiler_lock

    with global_compiler_lock:
        if sig in dispatcher.overloads:
            return True
        payload = pickle.loads(item[1])
        if tuple(payload[3].args) != tuple(sig):  # its signature: checked before any machine code
            return False
        dispatcher.targetctx.refresh()  # numba's runtime (NRT) and registries, as its cache's load does
        cres = _rebuild(dispatcher.targetctx, payload)
        dispatcher.targetctx.insert_user_function(cres.entry_point, cres.fndesc, [cres.library])
        dispatcher.add_overload(cres)
        dispatcher._cache.save_overload(sig, cres)  # a NullCache without the disk cache
    return True


def _rebuild(target_context, payload: tuple):
    """numba's ``CompileResult._rebuild`` for a library kept as bitcode, with the object code kept
    (numba's ``enable_object_caching``) so that the kernel can be saved to numba's cache."""
    from llvmlite import binding as ll
    from numba.core.compiler import CompileResult

    libdata, fndesc, env, signature, objectmode, lifted, typeann, reload_init, referenced_envs = payload
    name, kind, bitcode = libdata
    if kind != "bitcode":
        raise ValueError(f"bundle entry {name!r}: expected bitcode, got {kind!r}")
    for fn in reload_init or ():
        fn()
    library = target_context.codegen().create_library(name)
    library.enable_object_caching()
    library._final_module = ll.parse_bitcode(bitcode)
    library._finalize_final_module()
    cfunc = target_context.get_executable(library, fndesc, env)
    cres = CompileResult(
        target_context=target_context,
        typing_context=target_context.typing_context,
        library=library,
        environment=env,
        entry_point=cfunc,
        fndesc=fndesc,
        type_annotation=typeann,
        signature=signature,
        objectmode=objectmode,
        lifted=lifted,
        typing_error=None,
        call_helper=None,
        metadata=None,
        reload_init=reload_init,
        referenced_envs=referenced_envs,
    )
    for referenced in referenced_envs:
        library.codegen.set_env(referenced.env_name, referenced)
    return cres


def write_bundle(entries: list[dict], out: Path) -> int:
    """Compile each kernel list entry in this process and write the bundle to ``out``; returns how
    many entries it holds. The process's kernel folder must be empty (a kernel numba loads from its
    cache has no bitcode of its own module): run it in a fresh process (``record_kernels.py`` does)."""
    import importlib

    if not internals_tested():
        raise RuntimeError("a bundle is made only with the numba and llvmlite lanegraph was tested with")
    from llvmlite import binding as ll
    from numba.core import serialize
    from numba.core.codegen import CPUCodeLibrary

    # the bitcode of each library as LLVM's code generator gets it: it rewrites the module in place
    # as it makes machine code (its IR preparation for the target), and bitcode taken afterwards
    # would be prepared twice (the same values, other machine code)
    finalize = CPUCodeLibrary._finalize_final_module

    def _kept(self):
        self._lanegraph_bitcode = self._final_module.as_bitcode()
        return finalize(self)

    CPUCodeLibrary._finalize_final_module = _kept
    kernels = []  # (entry, kernel, signature), each compiled as it is resolved
    try:
        for entry in entries:
            kernel = getattr(importlib.import_module(str(entry["module"])), str(entry["name"]))
            sig = tuple(decode_type(str(a)) for a in entry["args"])
            kernel.compile(sig)
            kernels.append((entry, kernel, sig))
    finally:
        CPUCodeLibrary._finalize_final_module = finalize
    kept = {}
    for entry, kernel, sig in kernels:
        cres = kernel.overloads.get(sig)
        if cres is None or kernel.stats.cache_hits.get(sig, 0):
            raise RuntimeError(f"{entry_key(entry)}: not compiled in this process (empty the kernel folder)")
        reduced = cres._reduce()  # as numba's cache keeps it, the library then replaced by its bitcode
        # and the type annotation (a text for numba's ``inspect_types``, with the addresses of this
        # process's objects in it) by a note: the bundle is the same bytes for the same sources
        note = f"{entry_key(entry)}: from lanegraph's kernel bundle (no type annotation kept)"
        library = cres.library
        payload = ((library.name, "bitcode", library._lanegraph_bitcode), *reduced[1:6], note, *reduced[7:])
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
    "decode_type",
    "enabled",
    "encode_type",
    "environment",
    "install",
    "keys",
    "package_digest",
    "read_header",
    "read_list",
    "write_bundle",
]
