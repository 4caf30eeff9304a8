"""Safe loading of graph files: YAML (safe loader, duplicate keys rejected), JSON and TOML.

Loading never executes code: YAML is read with a safe loader (no ``!!python`` tags), files are
bounded in size and nesting depth, and ``extends`` may only point inside the allowed roots.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import tomllib
import yaml

from ..errors import GraphError, Problem

MAX_FILE_BYTES = 1_000_000
MAX_DEPTH = 32
MAX_VALUES = 200_000


class _UniqueKeyLoader(yaml.SafeLoader):
    """A safe YAML loader that rejects duplicate mapping keys (a duplicate node id, say)."""


def _construct_mapping(loader: _UniqueKeyLoader, node: yaml.MappingNode, deep: bool = False) -> dict:
    seen: dict[Any, int] = {}
    for key_node, _ in node.value:
        if key_node.tag == "tag:yaml.org,2002:merge":
            continue  # a '<<' merge key: its keys may be overridden by the mapping's own
        key = loader.construct_object(key_node, deep=True)
        try:
            hash(key)
        except TypeError:
            raise yaml.constructor.ConstructorError(
                None,
                None,
                f"found an unhashable key ({type(key).__name__}); keys must be plain scalars",
                key_node.start_mark,
            ) from None
        if key in seen:
            raise yaml.constructor.ConstructorError(
                None,
                None,
                f"duplicate key {key!r} (first at line {seen[key] + 1}); "
                "every key, node ids included, must be unique",
                key_node.start_mark,
            )
        seen[key] = key_node.start_mark.line
    return yaml.SafeLoader.construct_mapping(loader, node, deep=deep)


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def _too_big(obj: Any) -> str | None:
    """Why ``obj`` is out of bounds (nesting deeper than MAX_DEPTH, more than MAX_VALUES values,
    YAML aliases counted every time they are used), or None."""
    stack = [(obj, 0)]
    count = 0
    while stack:
        item, level = stack.pop()
        count += 1
        if count > MAX_VALUES:
            return f"more than {MAX_VALUES} values (YAML aliases counted each time they are used)"
        if isinstance(item, dict):
            children = item.values()
        elif isinstance(item, list):
            children = item
        else:
            continue
        if level >= MAX_DEPTH:
            return f"nesting deeper than {MAX_DEPTH} levels"
        stack.extend((c, level + 1) for c in children)
    return None


def _json_object(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"duplicate key {key!r}; every key, node ids included, must be unique")
        out[key] = value
    return out


def parse_text(text: str, fmt: str, source: str) -> Any:
    """Parse graph text of format ``yaml`` | ``json`` | ``toml``; errors name the source and line."""
    try:
        if fmt == "json":
            data = json.loads(text, object_pairs_hook=_json_object)
        elif fmt == "toml":
            data = tomllib.loads(text)
        else:
            data = yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 - a SafeLoader subclass
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f"line {mark.line + 1}, column {mark.column + 1}" if mark else "?"
        raise GraphError([Problem(f"invalid YAML at {where}: {exc.problem or exc}", file=source)]) from None
    except yaml.YAMLError as exc:
        raise GraphError([Problem(f"invalid YAML: {exc}", file=source)]) from None
    except json.JSONDecodeError as exc:
        raise GraphError([Problem(f"invalid JSON at line {exc.lineno}: {exc.msg}", file=source)]) from None
    except tomllib.TOMLDecodeError as exc:
        raise GraphError([Problem(f"invalid TOML: {exc}", file=source)]) from None
    except (
        ValueError
    ) as exc:  # a duplicate JSON key; a YAML value its tag cannot hold (!!int abc, 2011-13-45)
        raise GraphError([Problem(f"invalid {fmt.upper()}: {exc}", file=source)]) from None
    except RecursionError:  # the parsers recurse per nesting level
        raise GraphError([Problem(f"nesting deeper than {MAX_DEPTH} levels", file=source)]) from None
    why = _too_big(data)
    if why:
        raise GraphError([Problem(why, file=source)])
    return data


def read_graph_file(path: Path, display: str | None = None) -> dict[str, Any]:
    """Read one graph file into a plain dict (no ``extends`` resolution)."""
    shown = display or str(path)
    try:
        found = path.is_file()
    except (OSError, ValueError) as exc:  # a NUL byte, a name too long for the file system
        raise GraphError([Problem(f"invalid path: {exc}", file=shown)]) from None
    if not found:
        if path.is_symlink():
            try:
                path.stat()
            except OSError as exc:
                raise GraphError(
                    [Problem(f"a symbolic link that leads nowhere: {exc.strerror or exc}", file=shown)]
                ) from None
        if path.is_dir():
            raise GraphError([Problem("is a folder, not a graph file", file=shown)])
        raise GraphError([Problem("graph file not found", file=shown, hint="check the path")])
    size = path.stat().st_size
    if size > MAX_FILE_BYTES:
        raise GraphError(
            [Problem(f"file is {size} bytes; graph files are limited to {MAX_FILE_BYTES}", file=shown)]
        )
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise GraphError([Problem("not a UTF-8 text file", file=shown)]) from None
    except OSError as exc:
        raise GraphError([Problem(f"cannot read the file: {exc.strerror or exc}", file=shown)]) from None
    fmt = {".json": "json", ".toml": "toml"}.get(path.suffix.lower(), "yaml")
    data = parse_text(text, fmt, shown)
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise GraphError(
            [Problem(f"expected a mapping at the top level, got {type(data).__name__}", file=shown)]
        )
    return data
