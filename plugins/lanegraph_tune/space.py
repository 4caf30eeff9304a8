"""Search spaces of ``lanegraph tune``: which node params are searched, over which values.

A space file is YAML, read safely and validated by :class:`SpaceModel` (``extra="forbid"``):

.. code-block:: yaml

    description: the paint check's contrasts and the road mask's tolerance
    params:
      verify.min_paint_contrast: {low: 0.15, high: 0.45}          # a float range
      verify.min_painted_rows: {low: 4, high: 20, type: int}     # an int range
      roadmask.height_tolerance_m: {low: 0.04, high: 0.16, log: true}
      roadmask.keep: {choices: [bottom, bottom_centre]}          # a choice

Each key is ``node_id.param`` of the graph being tuned. :func:`load_space` checks the file against
the graph before anything runs: the node exists, the param is one of its params model's fields,
and the range's ends (or every choice) are values the params model accepts -- so a range outside
the param's bounds is refused with the bound, located as ``FILE: params.NODE.PARAM: ...``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from lanegraph.builtin import graph_names, graphs_dir
from lanegraph.errors import UsageError, did_you_mean


class ParamSpace(BaseModel):
    """One searched param: a range (``low``, ``high``, optional ``log``, ``step``, ``type``) or
    ``choices``."""

    model_config = ConfigDict(extra="forbid")

    low: float | None = Field(None, description="smallest value of a range (inclusive)")
    high: float | None = Field(None, description="largest value of a range (inclusive)")
    type: Literal["int", "float"] | None = Field(
        None, description="int or float; default: int when both ends are integers written without a point"
    )
    log: bool = Field(False, description="sample the range on a log scale (both ends > 0)")
    step: float | None = Field(None, gt=0, description="a range's grid step (optional; int ranges: 1)")
    choices: list[Any] | None = Field(
        None, min_length=1, description="the values to choose from (in place of a range)"
    )

    @model_validator(mode="after")
    def _range_or_choices(self) -> ParamSpace:
        if self.choices is not None:
            if self.low is not None or self.high is not None or self.log or self.step is not None:
                raise ValueError("give either choices or a range (low, high), not both")
            keys = [json.dumps(c, sort_keys=True) for c in self.choices]
            if len(set(keys)) != len(keys):
                raise ValueError(f"choices: a value is given twice: {self.choices}")
            return self
        if self.low is None or self.high is None:
            raise ValueError("expected a range (low and high) or choices")
        if not (math.isfinite(self.low) and math.isfinite(self.high)):
            raise ValueError(f"low and high must be finite numbers, got {self.low}, {self.high}")
        if self.low > self.high:
            raise ValueError(f"low ({self.low}) is above high ({self.high})")
        if self.log and self.low <= 0:
            raise ValueError(f"log: a log range needs low > 0, got low = {self.low}")
        if self.type == "int" and (self.low != int(self.low) or self.high != int(self.high)):
            raise ValueError(f"type int: low and high must be integers, got {self.low}, {self.high}")
        if self.log and self.step is not None:
            raise ValueError("step and log cannot be combined (Optuna samples a log range without a step)")
        return self


class SpaceModel(BaseModel):
    """A space file."""

    model_config = ConfigDict(extra="forbid")

    description: str | None = Field(None, description="what the space searches, in words")
    params: dict[str, ParamSpace] = Field(
        min_length=1, description="node_id.param -> its range or choices, in search order"
    )


@dataclass(frozen=True)
class SearchParam:
    """A searched param, checked against the graph: ``key`` is ``node.param``; ``kind`` is
    ``int``, ``float`` or ``choice``."""

    key: str
    kind: str
    low: float | None = None
    high: float | None = None
    log: bool = False
    step: float | None = None
    choices: tuple[Any, ...] = ()

    def suggest(self, trial: Any) -> Any:
        """The value an Optuna trial suggests for this param."""
        if self.kind == "choice":
            return trial.suggest_categorical(self.key, list(self.choices))
        if self.kind == "int":
            step = int(self.step) if self.step else 1
            return trial.suggest_int(self.key, int(self.low), int(self.high), step=step, log=self.log)
        return trial.suggest_float(self.key, self.low, self.high, step=self.step, log=self.log)

    def grid(self, points: int) -> list[Any]:
        """The values a grid search tries: the choices, every step of a stepped range (every int
        of an int range up to ``points``), else ``points`` values evenly (log-evenly) spread."""
        if self.kind == "choice":
            return list(self.choices)
        lo, hi = float(self.low), float(self.high)
        if self.step:
            n = int(math.floor((hi - lo) / self.step + 1e-9)) + 1
            vals = [lo + k * self.step for k in range(n)]
        elif self.kind == "int" and hi - lo + 1 <= points:
            vals = [lo + k for k in range(int(hi - lo) + 1)]
        elif points == 1 or lo == hi:
            vals = [lo]
        elif self.log:
            vals = [
                math.exp(math.log(lo) + k * (math.log(hi) - math.log(lo)) / (points - 1))
                for k in range(points)
            ]
        else:
            vals = [lo + k * (hi - lo) / (points - 1) for k in range(points)]
        if self.kind == "int":
            return list(dict.fromkeys(int(round(v)) for v in vals))
        return [round(v, 12) for v in vals]


@dataclass(frozen=True)
class Space:
    """A checked search space: its file, description and params in file order."""

    file: Path
    description: str | None
    params: tuple[SearchParam, ...]

    @property
    def keys(self) -> list[str]:
        return [p.key for p in self.params]

    def digest_text(self) -> str:
        return json.dumps([p.__dict__ for p in self.params], sort_keys=True, default=str)


def _model_errors(path: Path, exc: ValidationError) -> str:
    msgs = []
    for err in exc.errors():
        loc = [str(p) for p in err["loc"]]
        where = ".".join(loc) or "(top level)"
        msg = str(err["msg"]).removeprefix("Value error, ")
        got = err.get("input")
        extra = f", got {got!r}" if err["type"] == "extra_forbidden" or err["type"].endswith("_type") else ""
        msgs.append(f"{where}: {msg}{extra}")
    return f"{path}: " + "; ".join(msgs)


def read_space(path: str | Path) -> SpaceModel:
    """Read and validate a space file (no graph needed). Raises :class:`UsageError` naming the
    file and each field at fault."""
    path = resolve_space_path(path)
    if not path.is_file():
        raise UsageError(
            f"--space {path}: no such file (expected a YAML space file, or a built-in space: "
            f"{', '.join(graph_names('spaces')) or 'none'})"
        )
    try:
        text = path.read_text(encoding="utf-8")
        if len(text) > 1_000_000:
            raise UsageError(
                f"{path}: a space file of {len(text)} characters is too large (at most 1,000,000)"
            )
        raw = yaml.safe_load(text)
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise UsageError(f"{path}: not valid YAML ({exc})") from None
    if not isinstance(raw, dict):
        raise UsageError(f"{path}: expected a mapping with 'params', got {type(raw).__name__}")
    try:
        return SpaceModel.model_validate(raw)
    except ValidationError as exc:
        raise UsageError(_model_errors(path, exc)) from None


def resolve_space_path(path: str | Path) -> Path:
    """A space file's path, or the name of a built-in one (``spaces/paper``, found from any folder
    in lanegraph's graphs) when no file of that name is here."""
    path = Path(path)
    if path.is_file():
        return path
    name = path.as_posix().removesuffix(".yaml")
    if name in graph_names("spaces"):
        return graphs_dir() / f"{name}.yaml"
    return path


def _check_value(params_model: type, current: dict[str, Any], name: str, value: Any) -> str | None:
    """Why the params model refuses ``name = value`` (its message), or None."""
    try:
        params_model.model_validate({**current, name: value})
    except ValidationError as exc:
        for err in exc.errors():
            if err["loc"] and err["loc"][0] == name:
                return str(err["msg"])
        return "; ".join(str(e["msg"]) for e in exc.errors())
    return None


def check_space(model: SpaceModel, path: Path, graph: Any) -> Space:
    """``model`` checked against the validated ``graph`` (:meth:`lanegraph.api.Session.load_graph`):
    every problem at once in one :class:`UsageError`, each ``FILE: params.KEY: ...``."""
    problems: list[str] = []
    out: list[SearchParam] = []
    for key, spec in model.params.items():
        where = f"{path}: params.{key}"
        node_id, dot, name = key.partition(".")
        if not dot or not node_id or not name or "." in name:
            problems.append(f"{where}: expected node_id.param (a node of the graph and one of its params)")
            continue
        node = graph.nodes.get(node_id)
        if node is None:
            hint = did_you_mean(node_id, list(graph.nodes))
            problems.append(
                f"{where}: the graph {graph.file} has no node {node_id!r}" + (f"; {hint}" if hint else "")
            )
            continue
        pmodel = node.type.params
        fields = pmodel.model_fields
        if name not in fields:
            hint = did_you_mean(name, list(fields))
            problems.append(
                f"{where}: node {node_id!r} ({node.type.name}) has no param {name!r}"
                + (f"; {hint}" if hint else "")
            )
            continue
        current = node.params.model_dump()
        if spec.choices is not None:
            for c in spec.choices:
                why = _check_value(pmodel, current, name, c)
                if why:
                    problems.append(f"{where}: choice {c!r}: {node_id} ({node.type.name}).{name}: {why}")
            out.append(SearchParam(key, "choice", choices=tuple(spec.choices)))
            continue
        ann = fields[name].annotation
        kind = spec.type or ("int" if _is_int(ann, spec) else "float")
        if kind == "int" and spec.step is not None and spec.step != int(spec.step):
            problems.append(f"{where}: step: an int range takes an integer step, got {spec.step}")
        for end, value in (("low", spec.low), ("high", spec.high)):
            v = int(value) if kind == "int" else float(value)
            why = _check_value(pmodel, current, name, v)
            if why:
                problems.append(
                    f"{where}: {end} = {v}: out of {node_id} ({node.type.name}).{name}'s bounds: {why}"
                )
        out.append(SearchParam(key, kind, spec.low, spec.high, spec.log, spec.step))
    if problems:
        raise UsageError("; ".join(problems))
    return Space(path, model.description, tuple(out))


def _is_int(annotation: Any, spec: ParamSpace) -> bool:
    text = str(annotation)
    if annotation is int or text in ("int", "int | None", "typing.Optional[int]"):
        return True
    if annotation is float or "float" in text:
        return False
    return float(spec.low).is_integer() and float(spec.high).is_integer()


def load_space(path: str | Path, graph: Any) -> Space:
    """Read a space file and check it against the validated ``graph`` (see the module's doc)."""
    return check_space(read_space(path), resolve_space_path(path), graph)


def sets_of(params: dict[str, Any]) -> list[str]:
    """``--set`` items of chosen params (values written as JSON, which YAML reads back the same)."""
    return [f"{k}={json.dumps(v)}" for k, v in params.items()]
