"""Pictures for the report: the left images of the frames, read through the run's own source node
type (any installed source: the engine does not know input folder layouts), and the per-node
pictures that ``--debug-dir`` recorded; both written as reduced JPEG files."""

from __future__ import annotations

import re
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from lanegraph.api import detect_source, open_source, read_record, select_source
from lanegraph.errors import GraphError, LanegraphError, NodeError
from lanegraph.lifecycle import close
from lanegraph.plugins import PluginManager
from lanegraph.presentation.render import to_bgr

#: the ``--debug-dir`` picture of one node output: ``<node id>.<port>.png`` (node ids have no dot)
_PICTURE = re.compile(r"^(?P<node>[^.]+)\.(?P<port>.+)\.png$")

JPEG_QUALITY = 80


@dataclass
class SourceChoice:
    """The source node type (and params) that reads a sequence's frames, and why it was chosen."""

    node_type: Any  # lanegraph.nodes.NodeType
    params: Any  # its params model instance
    node_id: str = "src"


def choose_source(
    pm: PluginManager, graph: Any | None, input_path: Path | None, allow_default: bool
) -> SourceChoice | None:
    """The source that reads ``input_path``: the graph's source node (a selecting source replaced
    as the executor replaces it), else the installed source type that recognises the folder
    (``lanegraph_detect_source``), else, with ``allow_default`` and no input, what an installed
    selecting source chooses without an input (the built-in synthetic scene). None when nothing
    reads it."""
    if graph is not None:
        src = graph.source
        try:
            nt = select_source(pm, src.type, src.params, input_path)
        except GraphError:
            return None
        return SourceChoice(nt, src.params if nt is src.type else nt.params(), src.id)
    if input_path is None and not allow_default:
        return None
    nt = detect_source(pm, input_path)
    return SourceChoice(nt, nt.params()) if nt is not None else None


def read_left_images(
    choice: SourceChoice,
    input_path: Path | None,
    frames: slice | None,
    wanted: set[str],
    on_image: Callable[[str, np.ndarray], None],
    on_frame: Callable[[], None] | None = None,
) -> list[str]:
    """Iterate the source over ``input_path`` (``frames`` selected) and call ``on_image(frame,
    left)`` for each frame in ``wanted``, stopping once every wanted frame was seen; returns the
    source's frame ids in order, as far as it was read; ``on_frame()`` after each wanted frame.
    Frames the source cannot read are left out.

    Raises :class:`~lanegraph.errors.LanegraphError` when the source cannot be opened.
    """
    try:
        source = open_source(choice.node_type, choice.params, input_path, frames, choice.node_id)
    except NodeError as exc:  # a third-party source: reported, the report goes on
        raise LanegraphError(
            f"source {choice.node_type.name!r} could not be opened: {type(exc.cause).__name__}: {exc.cause}"
        ) from exc
    order: list[str] = []
    left_to_see = set(wanted)
    try:
        for item in source:
            if isinstance(item, BaseException) or not isinstance(item, dict):
                continue  # a frame the source cannot read: shown without its image
            frame = str(item.get("frame"))
            order.append(frame)
            if frame in left_to_see and item.get("left") is not None:
                on_image(frame, item["left"])
                left_to_see.discard(frame)
                if on_frame is not None:
                    on_frame()
                if not left_to_see:
                    break
    except LanegraphError:
        raise
    except Exception as exc:  # noqa: BLE001 - a third-party source: reported, the report goes on
        raise LanegraphError(
            f"source {choice.node_type.name!r} failed after {len(order)} frame(s): {type(exc).__name__}: {exc}"
        ) from exc
    finally:
        close(source, choice.node_type)
    return order


def reduced(image: np.ndarray, max_width: int, max_height: int | None = None) -> np.ndarray:
    """``image`` as BGR, scaled down (area interpolation) to at most ``max_width`` pixels wide
    and ``max_height`` high."""
    bgr = to_bgr(image)
    h, w = bgr.shape[:2]
    s = min(max_width / w, (max_height or h) / h)
    if s < 1:
        bgr = cv2.resize(bgr, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)
    return bgr


def write_jpeg(path: Path, image: np.ndarray, max_width: int, max_height: int | None = None) -> None:
    """Write ``image`` reduced to ``max_width`` x ``max_height`` as a JPEG file."""
    ok, buf = cv2.imencode(
        ".jpg", reduced(image, max_width, max_height), [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY]
    )
    if not ok:  # pragma: no cover - OpenCV encodes any BGR uint8 image
        raise LanegraphError(f"{path}: JPEG encoding failed")
    path.write_bytes(buf.tobytes())


class JpegWriter:
    """Encodes and writes JPEG files on worker threads (OpenCV releases the GIL while encoding)."""

    def __init__(self, workers: int = 2, pending: int = 8) -> None:
        self.pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="lanegraph-report")
        self.jobs: list[Future] = []
        self.slots = threading.BoundedSemaphore(pending)  # images waiting in memory, at most

    def _submit(self, fn: Callable[..., None], *args: Any) -> None:
        self.slots.acquire()
        job = self.pool.submit(fn, *args)
        job.add_done_callback(lambda _: self.slots.release())
        self.jobs.append(job)

    def submit(self, path: Path, image: np.ndarray, max_width: int) -> None:
        self._submit(write_jpeg, path, image, max_width)

    def submit_file(self, path: Path, picture: Path, max_width: int) -> None:
        self._submit(_convert, path, picture, max_width)

    def wait(self) -> list[str]:
        """Wait for every job; returns the errors of those that failed."""
        errors = []
        for job in self.jobs:
            exc = job.exception()
            if exc is not None:
                errors.append(str(exc))
        self.pool.shutdown()
        return errors


def _convert(path: Path, picture: Path, max_width: int) -> None:
    img = cv2.imread(str(picture), cv2.IMREAD_COLOR)
    if img is None:
        raise LanegraphError(f"{picture}: cannot decode the picture")
    write_jpeg(path, img, max_width, max_width)


# --------------------------------------------------------------------------- --debug-dir pictures
def debug_pictures(
    folder: Path, order: Sequence[str], ports: dict[str, Sequence[str]]
) -> list[tuple[str, Path]]:
    """The pictures of one frame's ``--debug-dir`` folder as ``(node.port, file)``, in graph order
    (``order``: node ids; ``ports``: node id -> its output ports in declaration order); pictures of
    nodes the graph does not know follow in the order they were written. The mosaic is left out."""
    rank = {nid: i for i, nid in enumerate(order)}
    found = []
    for p in folder.iterdir():
        m = _PICTURE.match(p.name)
        if not m or not p.is_file() or p.name == "mosaic.png":
            continue
        node, port = m.group("node"), m.group("port")
        port_rank = list(ports.get(node, ())).index(port) if port in ports.get(node, ()) else 99
        found.append(
            ((rank.get(node, len(rank)), port_rank, p.stat().st_mtime_ns, p.name), f"{node}.{port}", p)
        )
    found.sort(key=lambda t: t[0])
    return [(cap, p) for _, cap, p in found]


def recorded_debug_dir(run_dir: Path) -> Path | None:
    """The ``--debug-dir`` folder the run in ``run_dir`` wrote, as its ``run.json`` records it (a
    folder inside the run folder), or None: pictures in any other folder may be another run's."""
    record = read_record(run_dir)
    rel = record.debug_dir if record is not None else None
    if not rel or Path(rel).is_absolute() or ".." in Path(rel).parts:
        return None
    folder = run_dir / rel
    return folder if folder.is_dir() else None
