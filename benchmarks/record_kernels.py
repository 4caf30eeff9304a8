"""Write the kernel list of the first run's helper process (lanegraph.kernel_cache): the kernels the
default ``lanegraph run`` calls from Python, with their argument types, in the order it compiles
them. Run it after changing a kernel's signature or adding one to the default graph (a stale list
costs the first run time, never a result):

    python benchmarks/record_kernels.py [lanegraph/data/kernels.json] [-- RUN ARGS]
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def record(argv: list[str]) -> list[dict]:
    """The top-level kernels ``lanegraph run ARGV`` compiles, in order (in this process, with an
    empty kernel folder)."""
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["NUMBA_CACHE_DIR"] = os.path.join(tmp, "kernels")
        os.environ["LANEGRAPH_CACHE_DIR"] = os.path.join(tmp, "cache")
        os.environ["LANEGRAPH_PRECOMPILE"] = "0"
        import numba
        from numba.core import event

        from lanegraph.kernel_cache import encode_type

        numba.config.CACHE_DIR = os.environ["NUMBA_CACHE_DIR"]
        entries: list[dict] = []
        depth = [0]

        class _Record(event.Listener):
            def on_start(self, ev: event.Event) -> None:
                depth[0] += 1
                func = ev.data["dispatcher"].py_func
                args = [encode_type(t) for t in ev.data["args"]]
                if depth[0] == 1 and func.__module__.split(".")[0] != "numba" and None not in args:
                    entries.append({"module": func.__module__, "name": func.__qualname__, "args": args})

            def on_end(self, ev: event.Event) -> None:
                depth[0] -= 1

        event.register("numba:compile", _Record())
        from lanegraph.cli import main

        try:
            main(["run", "--quiet", "--out", os.path.join(tmp, "out"), *argv], standalone_mode=False)
        except SystemExit:
            pass
    return entries


def main() -> None:
    args = sys.argv[1:]
    run_args = args[args.index("--") + 1 :] if "--" in args else []
    args = args[: args.index("--")] if "--" in args else args
    out = Path(args[0]) if args else ROOT / "lanegraph" / "data" / "kernels.json"
    entries = record(run_args)
    text = ",\n".join(json.dumps(e) for e in entries)  # one kernel a line
    out.write_text(f"[\n{text}\n]\n", encoding="utf-8")
    print(f"{len(entries)} kernels -> {out}")


if __name__ == "__main__":
    main()
