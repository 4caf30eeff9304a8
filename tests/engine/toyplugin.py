"""A tiny plugin of toy node types, so engine tests do not depend on the real plugins."""

from __future__ import annotations

import numpy as np
from pydantic import Field

from lanegraph import NodeParams, Port, PortType, RunContext, hookimpl, node_type

KEY_SALT = {"salt": "v1"}  # tests change it to simulate a changed input file


class CountParams(NodeParams):
    n: int = Field(3, ge=1, le=1000, description="number of frames")
    fail_at: int = Field(-1, ge=-1, description="raise on this frame index (-1: never)")


@node_type(
    "toy.count",
    source=True,
    outputs={"frame": "frame_id", "value": "number", "calib": Port("calibration", rate="constant")},
    implements=("constants", "frame_key", "len"),
)
class Count:
    """Yields frames 0..n-1 with value = index."""

    def __init__(self, params: CountParams, context: RunContext):
        self.p = params
        self.sel = context.frames or slice(None)

    def constants(self):
        return {"calib": "CAL"}

    def frame_key(self, frame):
        return f"count:{frame}:{KEY_SALT['salt']}"

    def __len__(self):
        return len(range(self.p.n)[self.sel])

    def __iter__(self):
        for i in range(self.p.n)[self.sel]:
            yield {"frame": f"{i:04d}", "value": float(i)}


class ScaleParams(NodeParams):
    factor: float = Field(2.0, ge=-100, le=100, description="multiplier")
    fail_on: float = Field(-1.0, description="raise when the input equals this value")


@node_type("toy.scale", inputs={"x": "number"}, outputs={"y": "number"})
def scale(params: ScaleParams, x):
    """y = factor * x."""
    if x == params.fail_on:
        raise ValueError(f"boom on {x}")
    return {"y": params.factor * x}


@node_type("toy.add", inputs={"a": "number", "b": Port("number", optional=True)}, outputs={"y": "number"})
def add(params: NodeParams, a, b):
    """y = a + b (b = 0 when unconnected or None)."""
    return {"y": a + (b or 0.0)}


CALLS = {"const": 0}


@node_type("toy.from_calib", inputs={"calib": "calibration"}, outputs={"y": "number"})
def from_calib(params: NodeParams, calib):
    """Depends on a constant only: runs once per run."""
    CALLS["const"] += 1
    return {"y": 100.0}


@node_type("toy.image", inputs={"image": "image"}, outputs={"y": "number"})
def image_in(params: NodeParams, image):
    """Takes an image (for port-type mismatch tests)."""
    return {"y": 0.0}


@node_type("toy.collect", inputs={"frame": "frame_id", "x": "number"}, sink=True)
class Collect:
    """Records (frame, x) pairs in a list shared by the test."""

    out: list = []

    def __init__(self, params: NodeParams, context: RunContext):
        Collect.out = []

    def __call__(self, frame, x):
        Collect.out.append((frame, x))
        return {}


@hookimpl
def lanegraph_node_types():
    return [Count, Flaky, scale, add, from_calib, image_in, Collect]


class FlakyParams(NodeParams):
    n: int = Field(4, ge=1, description="number of frames")
    bad: int = Field(1, ge=-1, description="index of the frame that cannot be read")
    resume: bool = Field(False, description="yield the error and go on instead of raising")


@node_type("toy.flaky", source=True, outputs={"frame": "frame_id", "value": "number"})
class Flaky:
    """Like toy.count, but frame ``bad`` raises an InputError when read."""

    def __init__(self, params: FlakyParams, context: RunContext):
        self.p = params

    def __iter__(self):
        from lanegraph.errors import InputError

        for i in range(self.p.n):
            if i == self.p.bad and self.p.resume:
                yield InputError("truncated image", path=f"/data/{i:04d}.png", frame=f"{i:04d}")
                continue
            if i == self.p.bad:
                raise InputError("truncated image", path=f"/data/{i:04d}.png", frame=f"{i:04d}")
            yield {"frame": f"{i:04d}", "value": float(i)}


# --------------------------------------------------------------------------- a plugin's own value type
class Tally:
    """A plugin's own value type (not a dataclass): a running total and the values it has seen."""

    def __init__(self, total: float, seen: np.ndarray):
        self.total = float(total)
        self.seen = seen

    def __eq__(self, other):
        return type(other) is Tally and other.total == self.total and np.array_equal(other.seen, self.seen)


def encode_tally(t: Tally) -> dict:
    return {"total": t.total, "seen": t.seen}


def decode_tally(data) -> Tally:
    if not (
        isinstance(data, dict) and set(data) == {"total", "seen"} and isinstance(data["seen"], np.ndarray)
    ):
        raise ValueError("expected {total, seen}")
    return Tally(data["total"], data["seen"])


TALLY = PortType("tally", "a running total (toy)", stores=Tally, encode=encode_tally, decode=decode_tally)
CALLS["tally"] = 0


@node_type(
    "toy.tally",
    inputs={"x": "number", "prev": Port("tally", optional=True)},
    outputs={"tally": "tally", "total": "number"},
)
def tally(params: NodeParams, x, prev=None):
    """Adds x to the previous frame's tally (a feedback edge of the plugin's own type)."""
    CALLS["tally"] += 1
    seen = np.append(prev.seen if prev is not None else np.zeros(0, np.float32), np.float32(x))
    t = Tally((prev.total if prev is not None else 0.0) + x, seen)
    return {"tally": t, "total": t.total}


class TallyPlugin:
    """Registers the toy value type's port type (with its storage) and the node that makes it; not
    registered by the ``pm`` fixture."""

    @staticmethod
    @hookimpl
    def lanegraph_port_types():
        return [TALLY]

    @staticmethod
    @hookimpl
    def lanegraph_node_types():
        return [tally]
