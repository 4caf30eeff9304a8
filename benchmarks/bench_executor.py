"""Executor overhead per node per frame, against calling the same node functions directly.

    python benchmarks/bench_executor.py [--frames 2000] [--nodes 20]

Builds a chain of cheap nodes (so the node work is negligible and what is measured is the
engine's bookkeeping: input gathering, hooks, timing) and prints µs per node per frame.
Target: <= 50 µs.
"""

from __future__ import annotations

import argparse
import time

from pydantic import Field

from lanegraph import NodeParams, RunContext, hookimpl, node_type
from lanegraph.graph.validation import validate_raw
from lanegraph.plugins import PluginManager
from lanegraph.run.executor import Executor


class SrcParams(NodeParams):
    n: int = Field(1000, ge=1, description="frames")


@node_type("bench.src", source=True, outputs={"frame": "frame_id", "value": "number"})
class Src:
    """Frames with a number."""

    def __init__(self, params: SrcParams, context: RunContext):
        self.n = params.n

    def __len__(self):
        return self.n

    def __iter__(self):
        for i in range(self.n):
            yield {"frame": str(i), "value": float(i)}


class IncParams(NodeParams):
    step: float = Field(1.0, description="increment")


@node_type("bench.inc", inputs={"x": "number"}, outputs={"y": "number"})
def inc(params: IncParams, x):
    """y = x + step."""
    return {"y": x + params.step}


class Plugin:
    @staticmethod
    @hookimpl
    def lanegraph_node_types():
        return [Src, inc]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=2000)
    ap.add_argument("--nodes", type=int, default=20)
    a = ap.parse_args()
    pm = PluginManager()
    pm.register(Plugin, name="bench")
    nodes = {"src": {"type": "bench.src", "params": {"n": a.frames}}}
    prev = "src.value"
    for i in range(a.nodes):
        nodes[f"n{i}"] = {"type": "bench.inc", "inputs": {"x": prev}}
        prev = f"n{i}.y"
    g = validate_raw({"nodes": nodes}, {}, "<bench>", pm)

    t0 = time.perf_counter()
    Executor(g, RunContext(), pm).run()
    engine = time.perf_counter() - t0

    params = IncParams()
    t0 = time.perf_counter()
    for f in Src(SrcParams(n=a.frames), RunContext()):
        x = f["value"]
        for _ in range(a.nodes):
            x = inc(params, x=x)["y"]
    direct = time.perf_counter() - t0
    per = (engine - direct) / (a.frames * a.nodes) * 1e6
    print(f"frames={a.frames} nodes={a.nodes}")
    print(f"engine: {engine * 1e3:.1f} ms   direct calls: {direct * 1e3:.1f} ms")
    print(f"executor overhead: {per:.2f} us per node per frame (target <= 50 us)")


if __name__ == "__main__":
    main()
