"""Writing a synthetic sequence to disk in the ``io.folder`` layout, with its ground truth."""

from __future__ import annotations

import json
import shutil
from dataclasses import asdict
from pathlib import Path

import cv2
import numpy as np
import yaml

from .scene import SceneRenderer, SceneSpec


def disparity_to_png16(disparity: np.ndarray) -> np.ndarray:
    """KITTI's 16-bit disparity encoding: ``round(d * 256)``, 0 where invalid (``d <= 0``)."""
    d = np.where(disparity > 0, disparity, 0.0)
    return np.clip(np.round(d * 256.0), 0, 65535).astype(np.uint16)


def write_sequence(spec: SceneSpec, folder: str | Path, n: int, start: int = 0) -> Path:
    """Render frames ``start .. start + n - 1`` of ``spec`` into ``folder`` and return it.

    Layout (readable by ``io.folder``)::

        left/<stem>.png, right/<stem>.png   rectified BGR pair
        calib.yaml                          f, cx, cy, baseline (pixels, metres), width, height
        disparity/<stem>.png                exact left disparity, KITTI 16-bit (value * 256, 0 = sky)
        labels/<stem>.png                   left-view labels: 0 sky, 1 road, 2 object
        lanes_gt.jsonl                      lane ground truth, one line per frame (data README format)
        scene.json                          preset, seed, true pitch/roll (degrees and radians), height ...

    ``<stem>`` is the frame index with 10 digits, e.g. ``0000000003``.
    """
    if n < 1:
        raise ValueError(f"write_sequence: n: expected an integer >= 1, got {n}")
    folder = Path(folder)
    for sub in ("left", "right", "disparity", "labels"):
        (folder / sub).mkdir(parents=True, exist_ok=True)
    renderer = SceneRenderer(spec)
    c = renderer.calib
    calib = {"f": float(c.f), "cx": float(c.cx), "cy": float(c.cy), "baseline": float(c.baseline),
             "width": int(c.width), "height": int(c.height)}  # fmt: skip
    if c.fy is not None:
        calib["fy"] = float(c.fy)
    (folder / "calib.yaml").write_text(yaml.safe_dump(calib, sort_keys=False))
    lines = []
    for k in range(start, start + n):
        fr = renderer.render(k)
        cv2.imwrite(str(folder / "left" / f"{fr.frame}.png"), fr.left)
        cv2.imwrite(str(folder / "right" / f"{fr.frame}.png"), fr.right)
        cv2.imwrite(str(folder / "disparity" / f"{fr.frame}.png"), disparity_to_png16(fr.disparity))
        labels = fr.road_mask.astype(np.uint8) + 2 * fr.object_mask.astype(np.uint8)
        cv2.imwrite(str(folder / "labels" / f"{fr.frame}.png"), labels)
        lines.append(json.dumps(fr.lanes_gt))
    (folder / "lanes_gt.jsonl").write_text("\n".join(lines) + "\n")
    info = {
        "preset": spec.preset,
        "seed": spec.seed,
        "frames": [start, start + n],
        "pitch_deg": spec.pitch_deg,
        "roll_deg": spec.roll_deg,
        "pitch": spec.pitch,
        "roll": spec.roll,
        "height": spec.height,
        "calib": calib,
        "fps": spec.fps,
        "speed": spec.speed,
        "curvature": spec.curvature,
        "curvature_rate": spec.curvature_rate,
        "lateral_speed": spec.lateral_speed,
        "lane_change": spec.lane_change,
        "markings": [asdict(m) for m in renderer.markings],
        "overexposed": [k for k in range(start, start + n) if spec.is_overexposed(k)],
    }
    (folder / "scene.json").write_text(json.dumps(info, indent=2) + "\n")
    return folder


def write_pairs(specs: list[SceneSpec], folder: str | Path) -> Path:
    """Render frame 0 of each of ``specs`` (unrelated scenes: a folder of single stereo pairs, as a
    collection of photographs) into ``folder`` in the layout of :func:`write_sequence`, pair ``i``
    as stem ``i``; every spec must have the same calibration. Returns the folder."""
    if not specs:
        raise ValueError("write_pairs: specs: expected at least one SceneSpec")
    if any(sp.calib != specs[0].calib for sp in specs):
        raise ValueError(
            "write_pairs: specs: expected one calibration for every pair (a folder has one calib.yaml)"
        )
    folder = Path(folder)
    lines = []
    for i, spec in enumerate(specs):
        sub = write_sequence(spec, folder / "_pair", 1)
        stem = f"{i:010d}"
        for d in ("left", "right", "disparity", "labels"):
            (folder / d).mkdir(parents=True, exist_ok=True)
            (sub / d / "0000000000.png").replace(folder / d / f"{stem}.png")
        gt = json.loads((sub / "lanes_gt.jsonl").read_text().splitlines()[0])
        gt["frame"] = stem
        lines.append(json.dumps(gt))
        (sub / "calib.yaml").replace(folder / "calib.yaml")
    (folder / "lanes_gt.jsonl").write_text("\n".join(lines) + "\n")
    info = {"pairs": [{"preset": sp.preset, "seed": sp.seed} for sp in specs]}
    (folder / "scene.json").write_text(json.dumps(info, indent=2) + "\n")
    shutil.rmtree(folder / "_pair")
    return folder
