"""Dataset files: several sequences (an input folder and an optional ground truth each) named in one
YAML file, so that ``lanegraph eval``, ``lanegraph ablate`` and the sweeps report every sequence's
figures and the pooled ones.

.. code-block:: yaml

    name: dev
    description: the developer sequences under ../shared/data
    sequences:
      - name: drive_0001
        input: ../../../shared/data/kitti_raw/2011_09_26/2011_09_26_drive_0001_sync
        gt: ../../../shared/data/kitti_raw/2011_09_26/2011_09_26_drive_0001_sync/lanes_gt.jsonl
      - name: seq1
        input: ../../../shared/data/kitti_odometry/seq1
        gt: ../../../shared/data/kitti_odometry/seq1/lanes_gt.jsonl
        frames: "0:20"      # optional: A:B or A:B:S over the input's frames (the ground truth is cut alike)
        group: odometry     # optional: `lanegraph tune` leaves a whole group out per fold

Relative paths are relative to the dataset file. A sequence's ``name`` becomes a folder name of the
outputs (``OUT/<name>/...``), so it is a plain name: letters, digits, ``_ - .``, not ``.`` or ``..``.
The pooled figures evaluate every frame of every sequence as one set (a frame is counted once, in its
own sequence): the detection ratio over all frames, the precision over all reported lanes.
"""

from __future__ import annotations

import re
from collections.abc import Collection, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from ..errors import InputError, did_you_mean
from ..frames import parse_frames
from .metrics import evaluate, read_ground_truth, select_frames

_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.\-]*$")

#: the name of the pooled row in reports
POOLED = "all"


class _SequenceModel(BaseModel):
    model_config = ConfigDict(extra="forbid")

    name: str = Field(
        description="the sequence's name: a folder name of the outputs (letters, digits, _ - .)"
    )
    input: str = Field(
        description="input folder (KITTI raw drive, KITTI odometry sequence, folder of pairs), relative to the dataset file"
    )
    gt: str | None = Field(None, description="ground truth lanes_gt.jsonl, relative to the dataset file")
    frames: str | None = Field(
        None,
        description="frame selection A:B or A:B:S over the input's frames (the ground truth is cut alike)",
    )
    group: str | None = Field(
        None,
        description="a group of sequences (the same street, the same drive): `lanegraph tune` leaves a whole "
        "group out in a fold; default: the sequence is a group of its own",
    )

    @field_validator("frames")
    @classmethod
    def _selection(cls, v: str | None) -> str | None:
        parse_frames(v)
        return v

    @field_validator("name")
    @classmethod
    def _plain_name(cls, v: str) -> str:
        if not _NAME.match(v) or v in (".", "..") or v == POOLED:
            raise ValueError(
                f"expected a plain name (letters, digits, _ - .; not '.', '..' or '{POOLED}'), got {v!r}"
            )
        return v


class _DatasetModel(BaseModel):
    model_config = ConfigDict(extra="forbid")

    name: str | None = Field(None, description="the dataset's name (default: the file's stem)")
    description: str | None = None
    sequences: list[_SequenceModel] = Field(min_length=1, description="the sequences, in report order")


@dataclass(frozen=True)
class SequenceSpec:
    """One sequence of a dataset: absolute paths."""

    name: str
    input: Path
    gt: Path | None = None
    frames: slice | None = None
    group: str | None = None  # `lanegraph tune` leaves a group out per fold (None: its own)


@dataclass(frozen=True)
class Dataset:
    """A named list of sequences (``sequences`` in file order)."""

    name: str
    file: Path | None
    sequences: tuple[SequenceSpec, ...]

    def __iter__(self):
        return iter(self.sequences)

    def __len__(self) -> int:
        return len(self.sequences)

    @property
    def has_gt(self) -> bool:
        return any(s.gt is not None for s in self.sequences)


def single_sequence(input_path: Path | None, gt: Path | None = None, frames: slice | None = None) -> Dataset:
    """The dataset of one ``--input`` (``None``: the built-in synthetic scene), named after its folder."""
    if input_path is None:
        name = "synthetic"
    else:
        name = (
            "".join(ch if ch.isalnum() or ch in "_-." else "_" for ch in Path(input_path).resolve().name)
            or "input"
        )
        if name in (".", "..", POOLED):
            name = f"input_{name.strip('.')}"
    return Dataset(name, None, (SequenceSpec(name, input_path, gt, frames),))  # type: ignore[arg-type]


def load_dataset(path: str | Path, check_paths: bool = True) -> Dataset:
    """Read and validate a dataset file (a path, or a built-in name: ``datasets/kitti_lanes``);
    paths are resolved relative to it. Its errors are exit 2: a dataset file is read before any
    frame runs.

    Raises
    ------
    InputError
        naming the file and, where it is one sequence's fault, the sequence and its field: a file
        that is not YAML, a field of the wrong type, a duplicate name, or (``check_paths``) an input
        folder or ground-truth file that does not exist.
    """
    try:
        return _load_dataset(path, check_paths)
    except InputError as exc:
        exc.exit_code = 2  # refused before any frame
        raise


def _load_dataset(path: str | Path, check_paths: bool) -> Dataset:
    from ..builtin import find_dataset, graph_names

    path = find_dataset(path)
    if not path.is_file():
        hint = did_you_mean(path.with_suffix("").as_posix().removeprefix("graphs/"), graph_names("datasets"))
        raise InputError(
            "dataset file not found (expected a YAML file listing sequences, or a built-in name"
            + (f"; {hint}" if hint else ": `lanegraph graphs` lists them")
            + ")",
            path=str(path),
        )
    try:
        raw = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise InputError(f"not valid YAML ({exc})", path=str(path)) from None
    try:
        model = _DatasetModel.model_validate(raw)
    except ValidationError as exc:
        msgs = []
        for err in exc.errors():
            loc = err["loc"]
            where = ".".join(str(p) for p in loc) or "(top level)"
            if len(loc) >= 2 and loc[0] == "sequences" and isinstance(loc[1], int) and isinstance(raw, dict):
                seqs = raw.get("sequences") or []
                if loc[1] < len(seqs) and isinstance(seqs[loc[1]], dict) and "name" in seqs[loc[1]]:
                    where = f"sequence {seqs[loc[1]]['name']!r}: " + ".".join(str(p) for p in loc[2:])
            msgs.append(f"{where}: {err['msg']}")
        raise InputError("; ".join(msgs), path=str(path)) from None
    base = path.resolve().parent
    seen: set[str] = set()
    seqs = []
    for s in model.sequences:
        if s.name in seen:
            raise InputError(
                f"sequence {s.name!r}: the name is used twice (names become output folders)", path=str(path)
            )
        seen.add(s.name)
        inp = (base / s.input).resolve()
        gt = (base / s.gt).resolve() if s.gt else None
        if check_paths:
            if not inp.exists():
                raise InputError(f"sequence {s.name!r}: input: {inp}: no such folder", path=str(path))
            if gt is not None and not gt.is_file():
                raise InputError(f"sequence {s.name!r}: gt: {gt}: no such file", path=str(path))
        seqs.append(SequenceSpec(s.name, inp, gt, parse_frames(s.frames), s.group))
    return Dataset(model.name or path.stem, path, tuple(seqs))


def read_gt(seq: SequenceSpec, frames: slice | None = None) -> list[dict[str, Any]] | None:
    """The sequence's ground-truth records, cut to ``frames`` (the ground truth lists the input's
    frames in order); ``None`` without ground truth."""
    if seq.gt is None:
        return None
    gt = read_ground_truth(seq.gt)
    return gt[frames] if frames is not None else gt


def evaluate_sequences(
    pairs: Iterable[tuple[str, list[Mapping[str, Any]], list[Mapping[str, Any]]]],
    frames: Mapping[str, Collection[str] | slice | None] | None = None,
) -> dict[str, dict[str, Any]]:
    """Evaluate ``(name, predictions, ground truth)`` per sequence and pooled.

    ``frames``: per sequence name, the frames to score (:func:`lanegraph.evaluation.metrics.select_frames`:
    the ids its run selected, or a slice of its ground truth); a sequence not named is scored whole.
    Returns ``{name: result, ..., "all": pooled}`` with the keys of :func:`lanegraph.evaluation.metrics.evaluate`
    (``per_frame`` left out); the pooled result's failed frames are named ``<sequence>/<frame>``, its
    ``frames_not_run`` is the sum of the sequences'.
    """
    out: dict[str, dict[str, Any]] = {}
    pooled_pred: list[dict[str, Any]] = []
    pooled_gt: list[dict[str, Any]] = []
    for name, pred, gt in pairs:
        gt, not_run = select_frames(gt, (frames or {}).get(name))
        res = evaluate(pred, gt)
        res.pop("per_frame")
        res["frames_not_run"] = not_run
        out[name] = res
        pooled_pred += [{**p, "frame": f"{name}/{p.get('frame')}"} for p in pred]
        pooled_gt += [{**g, "frame": f"{name}/{g.get('frame')}"} for g in gt]
    res = evaluate(pooled_pred, pooled_gt)
    res.pop("per_frame")
    res["frames_not_run"] = sum(r["frames_not_run"] for r in out.values())
    out[POOLED] = res
    return out
