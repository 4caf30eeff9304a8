"""The ``--debug-dir`` recorder.

:class:`DebugRecorder` is a plugin that ``lanegraph run --debug-dir DIR`` registers: for each
chosen frame it writes ``DIR/<frame>/<node>.<port>.png`` for every node output (drawn by its port
type, :func:`lanegraph.presentation.port_types.render_value`, or by the node type's own
``lanegraph_render``) and ``DIR/<frame>/mosaic.png`` with all of them side by side, captioned.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..errors import UsageError
from ..hookspecs import hookimpl
from ..paths import inside, safe_name, write_bytes_atomic
from ..plugins import call_hook
from ..run.task import Subscriber
from .port_types import render_value
from .render import mosaic, to_bgr


# --------------------------------------------------------------------------- the recorder plugin
class DebugRecorder:
    """A plugin that saves every node output of the chosen frames as pictures, and a mosaic.

    ``frames``: frame ids to record (``None``: all). Pictures go to ``out_dir/<frame>/`` as
    ``<node>.<port>.png`` plus ``mosaic.png``. A node type's own rendering (the
    ``lanegraph_render`` hook of any plugin) is used when it returns an image.
    """

    def __init__(self, out_dir: Path | str, frames: set[str] | None = None, pm: Any = None) -> None:
        self.out_dir = Path(out_dir)
        self.frames = frames
        self.pm = pm
        self.written: dict[str, list[Path]] = {}
        self.matched: set[str] = set()  # the entries of ``frames`` that matched a frame
        self._frame: str | None = None
        self._tiles: list[tuple[str, np.ndarray]] = []
        self._context: dict[str, Any] = {}
        self._constants: dict[str, Any] = {}

    def wants(self, frame: str) -> bool:
        """Whether ``frame`` is chosen: by its id, or by its number (``7`` matches ``0000000007``)."""
        if self.frames is None:
            return True
        hits = {
            f for f in self.frames if f == frame or (frame.isdigit() and f.isdigit() and int(f) == int(frame))
        }
        self.matched |= hits
        return bool(hits)

    def _folder(self, frame: str) -> Path:
        """The frame's folder: one safe name, resolved inside ``out_dir`` (never above it)."""
        folder = inside(self.out_dir, safe_name(frame), "--debug-dir")
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UsageError(f"--debug-dir: cannot create {folder}: {exc.strerror or exc}") from None
        return folder

    @staticmethod
    def _write(path: Path, img: np.ndarray) -> None:
        try:
            ok, png = cv2.imencode(".png", img)
            if not ok:
                raise UsageError(f"--debug-dir: cannot encode {path.name} as PNG")
            write_bytes_atomic(path, png.tobytes())  # never through a link planted at its name
        except (cv2.error, OSError) as exc:
            raise UsageError(f"--debug-dir: cannot write {path}: {exc}") from None

    # -- helpers
    def _port_type(self, node_type: str, port: str) -> str:
        nt = self.pm.get_node_type(node_type) if self.pm is not None else None
        if nt is None or port not in nt.outputs:
            return "any"
        return nt.outputs[port].type

    def _render(self, node_type: str, port: str, port_type: str, value: Any) -> np.ndarray | None:
        if self.pm is not None:
            img = call_hook(self.pm, "lanegraph_render", node_type=node_type, port=port, value=value)
            if img is not None:
                return to_bgr(img)
        types = self.pm.port_types if self.pm is not None else None
        return render_value(port_type, value, {**self._constants, **self._context}, types)

    def _flush(self) -> None:
        frame, tiles = self._frame, self._tiles
        self._frame, self._tiles, self._context = None, [], {}
        if frame is not None and tiles:
            path = self._folder(frame) / "mosaic.png"
            self._write(path, mosaic(tiles))
            self.written.setdefault(frame, []).append(path)

    # -- hooks
    @hookimpl
    def lanegraph_run_start(self) -> None:
        self._flush()
        self._constants = {}

    @hookimpl
    def lanegraph_after_node(
        self, node_id: str, node_type: str, frame: str | None, outputs: dict[str, Any] | None
    ) -> None:
        if not outputs:
            return
        if frame is None:  # constant outputs (calibration, BEV grid): context for every frame
            for port, value in outputs.items():
                self._constants.setdefault(self._port_type(node_type, port), value)
            return
        if not self.wants(frame):
            return
        if frame != self._frame:
            self._flush()
            self._frame = frame
        folder = self._folder(frame)
        typed = []
        for port, value in outputs.items():  # context first: a node's outputs are drawn over each other
            port_type = self._port_type(node_type, port)
            if port_type == "any" and isinstance(value, np.ndarray) and value.ndim == 3:
                port_type = "image"
            typed.append((port, port_type, value))
            if port_type in ("image", "gray"):
                self._context.setdefault(
                    "image", value
                )  # the first image of a frame (the left one) is the base
            else:
                self._context[port_type] = value
        for port, port_type, value in typed:
            if port_type == "frame_id":
                continue
            img = self._render(node_type, port, port_type, value)
            if img is None:
                continue
            path = folder / f"{safe_name(node_id)}.{safe_name(port)}.png"
            self._write(path, img)
            self.written.setdefault(frame, []).append(path)
            self._tiles.append((f"{node_id}.{port}", img))

    @hookimpl
    def lanegraph_run_end(self) -> None:
        self._flush()


class DebugPictures(Subscriber):
    """``--debug-dir`` for a task (:mod:`lanegraph.run.task`): a :class:`DebugRecorder` into
    ``folder`` registered while the run runs; the chosen ``frames`` that matched none are said in
    the run's record. Plain data until the run starts, so it travels with the task to a worker."""

    def __init__(self, folder: Path | str, frames: tuple[str, ...] | None = None):
        self.folder, self.frames = str(folder), frames
        self.recorder: DebugRecorder | None = None

    def started(self, task: Any, ex: Any, folder: Path) -> None:
        chosen = set(self.frames) if self.frames is not None else None
        self.recorder = DebugRecorder(Path(self.folder), chosen, ex.pm)
        ex.pm.register(self.recorder)

    def ended(self, task: Any, result: Any) -> None:
        recorder, self.recorder = self.recorder, None
        if recorder is None:
            return
        recorder.pm.unregister(recorder)
        missed = sorted(f for f in self.frames or () if f not in recorder.matched)
        if missed:  # said at the end and in run.json's warnings
            result.notes.append(
                f"--debug-frames {', '.join(missed)} matched no frame of the run; nothing recorded for them"
            )
