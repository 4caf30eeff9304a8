"""A run folder's record: ``run.json`` (what the run did) and ``timings.json`` (how long it took).

``run.json`` is a contract: ``ablate`` reuses a run by it, ``eval``, ``report`` and ``results`` find a
run's files through it, and a person reads it to learn how a folder was made. It is the
:class:`RunRecord` model, versioned (:data:`RECORD_VERSION`), written by :func:`write_run_files`
alone and read back by :func:`read_record` alone; it is built in one place, :meth:`RunRecord.of`,
which :mod:`lanegraph.run.task` alone calls (a test asserts it). A record of an older lanegraph (no
``version``) or one written by hand reads with the defaults for what it lacks; fields this version
does not know are left out (a misspelt field is never written: the model has no extras).

``command.json`` (an ablation or a dataset run as a whole, beside its runs' ``run.json``) is the
:class:`CommandRecord` model, written by :func:`write_command_record` alone.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from .. import paths
from ..errors import InputError

#: the version of the record this lanegraph writes (a record without one is version 0)
RECORD_VERSION = 2  # 2: command, overrides, selection, versions, git, identity, written (issue 30)
RECORD_NAME = "run.json"
TIMINGS_NAME = "timings.json"


class Stopped(BaseModel):
    """Where and why a run stopped."""

    error: str | None = None
    node: str | None = None
    frame: str | int | None = None


class Selection(BaseModel):
    """The frames a run selected: the ``--frames`` text (``""``: every frame) and the ids of the
    frames it consumed, done or failed (what ``eval`` and ``report`` score)."""

    frames: str = ""
    ids: list[str] = Field(default_factory=list)


class Provenance(BaseModel):
    """How a result was made (issue 30), as a run's and a command's record say it: the command
    line, the ``--set`` overrides, the versions of what computed it and the git commit of the
    graph's checkout (:meth:`lanegraph.service.Session.provenance` fills it)."""

    model_config = ConfigDict(extra="forbid")

    command: list[str] = Field(default_factory=list)
    overrides: list[str] = Field(default_factory=list)
    versions: dict[str, Any] = Field(default_factory=dict)
    git: dict[str, str] | None = None


class RunRecord(BaseModel):
    """The content of ``run.json``.

    ``status``: ``ok``, ``failed frames`` (some frames failed and the run went on) or ``stopped``
    (``stopped`` and ``error`` say why); ``results``: the sinks' result files by kind, relative to
    the folder (:mod:`lanegraph.records.results`); ``timings``: a copy of ``timings.json`` (what
    ``ablate`` tabulates when it reuses a run); ``before_any_frame``: the run stopped before its
    first frame (an unusable input)."""

    version: int = 0
    graph: str | None = None
    input: str | None = None
    sequence: str | None = None
    status: Literal["ok", "failed frames", "stopped"] | None = None
    error: str | None = None
    frames_ok: int = 0
    resumed_frames: int = 0
    failures: list[dict[str, Any]] = Field(default_factory=list)
    warnings: list[str] = Field(default_factory=list)
    results: dict[str, str] = Field(default_factory=dict)
    timings: dict[str, Any] | None = None
    stopped: Stopped | None = None
    before_any_frame: bool = False
    #: how it was made (issue 30): the command line, the ``--set`` overrides, the frames selected,
    #: the versions of what computed it, the git commit of the graph's checkout, what makes it
    #: this run (:mod:`lanegraph.records.folder`), and what lanegraph wrote in the folder
    command: list[str] = Field(default_factory=list)
    overrides: list[str] = Field(default_factory=list)
    selection: Selection | None = None
    versions: dict[str, Any] = Field(default_factory=dict)
    git: dict[str, str] | None = None
    identity: dict[str, Any] | None = None
    debug_dir: str | None = None
    written: list[str] = Field(default_factory=list)

    @field_validator("results", mode="before")
    @classmethod
    def _named_files(cls, v: Any) -> dict[str, str]:
        """Only kinds that name a file: a malformed entry is as if it were absent."""
        if not isinstance(v, dict):
            return {}
        return {str(k): p for k, p in v.items() if isinstance(p, str) and p}

    @field_validator("failures", mode="before")
    @classmethod
    def _failure_objects(cls, v: Any) -> list[dict[str, Any]]:
        return [f for f in v if isinstance(f, dict)] if isinstance(v, list) else []

    @classmethod
    def of(
        cls,
        result: Any,
        *,
        graph: str | None = None,
        input: str | None = None,
        sequence: str | None = None,
        stopped: Stopped | None = None,
        timings: dict[str, Any] | None = None,
        before_any_frame: bool = False,
        frames: str | None = None,
        frame_ids: list[str] | None = None,
        provenance: Provenance | None = None,
        identity: dict[str, Any] | None = None,
        debug_dir: str | None = None,
        written: list[str] | None = None,
    ) -> RunRecord:
        """The record of a run's :class:`~lanegraph.run.executor.RunResult` (and where it stopped);
        ``frames``: the ``--frames`` text of its selection, recorded with ``frame_ids`` (default:
        the ids of the frames the result consumed); ``provenance``: how it was made."""
        status = "stopped" if stopped is not None else ("failed frames" if result.failures else "ok")
        made = provenance or Provenance()
        ids = list(frame_ids) if frame_ids is not None else list(getattr(result, "frame_ids", []))
        return cls(
            version=RECORD_VERSION,
            graph=graph,
            input=input,
            sequence=sequence,
            status=status,
            error=stopped.error if stopped is not None else None,
            frames_ok=result.frames,
            resumed_frames=result.resumed_frames,
            failures=[f.to_json() for f in result.failures],
            warnings=result.warnings(),
            results=dict(result.results),
            timings=timings if timings is not None else result.timings_json(),
            stopped=stopped,
            before_any_frame=before_any_frame,
            command=list(made.command),
            overrides=list(made.overrides),
            selection=Selection(frames=frames or "", ids=ids),
            versions=dict(made.versions),
            git=made.git,
            identity=identity,
            debug_dir=debug_dir,
            written=list(written or []),
        )

    def to_json(self) -> str:
        data = self.model_dump(mode="json", exclude_none=False)
        if self.stopped is None:
            data.pop("stopped")
        return json.dumps(data, indent=2) + "\n"


def stopped_by(exc: BaseException) -> Stopped:
    """The ``stopped`` entry of a run that ``exc`` ended."""
    from ..errors import LanegraphError

    message = str(exc) if isinstance(exc, LanegraphError) else f"{type(exc).__name__}: {exc}"
    return Stopped(error=message, node=getattr(exc, "node_id", None), frame=getattr(exc, "frame", None))


def write_run_files(folder: Path, record: RunRecord, timings: dict[str, Any] | None = None) -> None:
    """The one writer of ``run.json`` (and ``timings.json``: ``timings``, default the record's), each
    replaced atomically. Raises :class:`OSError` when they cannot be written (a full disk)."""
    folder = Path(folder)
    timings = timings if timings is not None else (record.timings or {})
    paths.write_text_atomic(folder / TIMINGS_NAME, json.dumps(timings, indent=2) + "\n")
    paths.write_text_atomic(folder / RECORD_NAME, record.to_json())


def read_record(folder: Path, *, strict: bool = False, empty: bool = False) -> RunRecord | None:
    """The record of run folder ``folder``; None when it has none (``empty``: a record with every
    default instead). A file that is not a record is None too, or with ``strict`` an
    :class:`~lanegraph.errors.InputError` naming the file."""
    path = Path(folder) / RECORD_NAME
    if not path.is_file():
        return RunRecord() if empty else None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        if strict:
            raise InputError(f"not valid JSON ({exc})", path=str(path)) from None
        return None
    if not isinstance(data, dict):
        if strict:
            raise InputError("expected a JSON object", path=str(path))
        return None
    try:
        return RunRecord.model_validate(data)
    except ValidationError as exc:
        if strict:
            first = exc.errors()[0]
            where = ".".join(str(p) for p in first["loc"])
            raise InputError(f"{where}: {first['msg']}", path=str(path)) from None
        return None


COMMAND_NAME = "command.json"


class VariantEntry(BaseModel):
    """One variant of an ablation, as its ``command.json`` lists it."""

    model_config = ConfigDict(extra="forbid")

    name: str
    graph: str
    sets: list[str] = Field(default_factory=list)


class TuneEntry(BaseModel):
    """What a tune searched: its graph, its space file and the search's options."""

    model_config = ConfigDict(extra="forbid")

    graph: str
    space: str
    options: dict[str, Any] = Field(default_factory=dict)


class CommandRecord(BaseModel):
    """The content of ``command.json``: an ablation or a dataset run as a whole -- its ``kind``, how
    it was made (the fields of :class:`Provenance`), its variants (an ablation's), its ``identity``
    (:mod:`lanegraph.records.folder`) and what it wrote in its folder."""

    model_config = ConfigDict(extra="forbid")

    kind: Literal["dataset", "ablation", "tune"]
    command: list[str] = Field(default_factory=list)
    overrides: list[str] = Field(default_factory=list)
    versions: dict[str, Any] = Field(default_factory=dict)
    git: dict[str, str] | None = None
    variants: list[VariantEntry] | None = None
    identity: dict[str, Any] | None = None
    written: list[str] = Field(default_factory=list)
    #: a tune's graph, space file and search options (``lanegraph tune``)
    search: TuneEntry | None = None

    @classmethod
    def of(
        cls,
        kind: Literal["dataset", "ablation", "tune"],
        provenance: Provenance,
        identity: dict[str, Any],
        written: list[str],
        variants: list[VariantEntry] | None = None,
        search: TuneEntry | None = None,
    ) -> CommandRecord:
        """The one place a command's record is built."""
        return cls(
            kind=kind, **provenance.model_dump(), variants=variants, identity=identity, written=written,
            search=search,
        )  # fmt: skip

    def to_json(self) -> str:
        return json.dumps(self.model_dump(mode="json", exclude_none=True), indent=2) + "\n"


def write_command_record(folder: Path, record: CommandRecord) -> None:
    """The one writer of ``OUT/command.json`` (replaced atomically)."""
    paths.write_text_atomic(Path(folder) / COMMAND_NAME, record.to_json())
