"""``python -m lanegraph.kernels helper CLAIMS``: the first run's helper process
(:mod:`.first_run`); ``python -m lanegraph.kernels bundle LIST OUT [LIST OUT ...]``: write bundles
(:mod:`.bundle`, in a process with an empty kernel folder)."""

from __future__ import annotations

import sys

from . import bundle, first_run

if __name__ == "__main__":
    command, args = (sys.argv[1], sys.argv[2:]) if len(sys.argv) > 1 else ("", [])
    if command == "helper":
        sys.exit(first_run._main(args))
    if command == "bundle":
        sys.exit(bundle._main(args))
    print(
        "usage: python -m lanegraph.kernels helper CLAIMS | bundle LIST OUT [LIST OUT ...]", file=sys.stderr
    )
    sys.exit(2)
