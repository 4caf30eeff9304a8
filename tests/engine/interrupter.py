"""A plugin for the resume tests: interrupts the process that loads it at a chosen point of a run.

``LANEGRAPH_TEST_INTERRUPT="SIGNAL:NODE:WHEN:N"`` (``INT``, ``TERM``, ``HUP`` or ``KILL``; a node id; ``before`` or
``after`` the node; the N-th frame this process gives that node, from 1) sends the signal to the
process itself there: SIGKILL ends it at once, SIGINT raises KeyboardInterrupt as Ctrl-C does.
``after`` the sink ``write`` is the narrowest point: the line is written, the checkpoint is not.

Run through :data:`DRIVER`: ``python -c DRIVER run ...`` is ``lanegraph run ...`` with it loaded.
"""

from __future__ import annotations

import os
import signal

from lanegraph import hookimpl

DRIVER = (
    "import sys; sys.path.insert(0, sys.argv.pop(1)); import interrupter; "
    "from lanegraph.plugins import get_plugin_manager; get_plugin_manager().register(interrupter.Interrupter()); "
    "from lanegraph.cli import main; main(prog_name='lanegraph')"
)


class Interrupter:
    def __init__(self) -> None:
        spec = os.environ.get("LANEGRAPH_TEST_INTERRUPT", "")
        self.sig = self.node = self.when = None
        self.n = 0
        if spec:
            sig, self.node, self.when, n = spec.split(":")
            self.sig = {
                "INT": signal.SIGINT,
                "KILL": signal.SIGKILL,
                "TERM": signal.SIGTERM,
                "HUP": signal.SIGHUP,
            }[sig]
            self.n = int(n)
        self.seen = 0

    def _maybe(self, node_id: str, frame: str | None, when: str) -> None:
        if self.sig is None or frame is None or node_id != self.node or when != self.when:
            return
        self.seen += 1
        if self.seen == self.n:
            os.kill(os.getpid(), self.sig)

    @hookimpl
    def lanegraph_before_node(self, node_id, frame):
        self._maybe(node_id, frame, "before")

    @hookimpl
    def lanegraph_after_node(self, node_id, frame):
        self._maybe(node_id, frame, "after")
