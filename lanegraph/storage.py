"""How a port value is stored: data only, through its port type's ``encode`` / ``decode``.

A run stores values in two places: the checkpoint (``checkpoint.json``: the feedback edges'
values, :mod:`lanegraph.records.resume`) and the result cache (:mod:`lanegraph.run.cache`). Both hold
*data* -- JSON scalars, lists, tagged tuples and dicts, numeric NumPy arrays and scalars -- never a
pickled object, so that reading a crafted file can build nothing but data. A value of another class
is stored by the port type that registered it (as datasette's column types carry their own
storage): a :class:`~lanegraph.types.PortType` with ``stores`` (the class), ``encode(value) ->
data`` and ``decode(data) -> value``. lanegraph's own value types (:mod:`lanegraph.port_types`) are
stored that way too, and a plugin's are, once its ``lanegraph_port_types`` registers them::

    PortType("track", "a tracked object", stores=Track, encode=encode_track, decode=decode_track)
    PortType("pose", "a camera pose", **dataclass_storage(Pose))   # a dataclass: its fields

:func:`encode_value` turns a value into data (``arrays="base64"``: JSON text, the checkpoint;
``arrays="native"``: arrays kept as arrays, for the cache's restricted pickle) and
:func:`decode_value` back; both raise :class:`StorageError` naming where the value is. ``codecs``
(:func:`codecs_of`: the registered port types' storage by class and by name) are a plugin
manager's ``port_types``, or lanegraph's own (:data:`lanegraph.port_types.PORT_TYPES`).
"""

from __future__ import annotations

import base64
import dataclasses
import hashlib
import json
import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

MAX_BYTES = 1 << 30  #: the largest array a stored value may hold
MAX_NDIM = 32  #: numpy's own limit on dimensions
MAX_DIM = 1 << 31  #: the longest side of an array a stored value may hold
#: what the cache keeps as it is (its restricted unpickler builds these and nothing else)
_NATIVE = (bytes, bytearray, complex, set, frozenset, range, slice)


class StorageError(ValueError):
    """A value that cannot be stored (on writing) or a malformed stored value (on reading)."""


def digest(*parts: Any) -> str:
    """A stable hex digest of JSON-able parts (a cache key, a source's frame key)."""
    h = hashlib.sha256()
    for p in parts:
        h.update(json.dumps(p, sort_keys=True, default=str).encode())
        h.update(b"\0")
    return h.hexdigest()


class Codecs:
    """The storage of the registered port types: ``by_class`` (the class a port type ``stores``)
    and ``by_name``. Built once per run (:func:`codecs_of`)."""

    def __init__(self, port_types: Mapping[str, Any]):
        stored = [pt for pt in port_types.values() if pt.stores is not None]
        self.by_class: dict[type, Any] = {pt.stores: pt for pt in stored}
        self.by_name: dict[str, Any] = {pt.name: pt for pt in stored}


def codecs_of(port_types: Mapping[str, Any] | Codecs | None) -> Codecs:
    """The :class:`Codecs` of ``port_types`` (a plugin manager's ``port_types``; lanegraph's own
    are :data:`lanegraph.port_types.PORT_TYPES`); None: none, plain data only."""
    if isinstance(port_types, Codecs):
        return port_types
    return Codecs(port_types or {})


def dataclass_storage(cls: type) -> dict[str, Any]:
    """``stores``, ``encode`` and ``decode`` for a dataclass stored as its ``__init__`` fields
    (``PortType(..., **dataclass_storage(Pose))``); decoding refuses any other set of fields."""
    known = [f.name for f in dataclasses.fields(cls) if f.init]

    def encode(value: Any) -> dict[str, Any]:
        return {name: getattr(value, name) for name in known}

    def decode(data: Any) -> Any:
        if not isinstance(data, dict) or set(data) != set(known):
            got = sorted(data) if isinstance(data, dict) else type(data).__name__
            raise StorageError(f"a {cls.__name__} has the fields {sorted(known)}, got {got}")
        return cls(**data)

    return {"stores": cls, "encode": encode, "decode": decode}


# --------------------------------------------------------------------------- encoding
def encode_value(
    value: Any, where: str = "value", codecs: Mapping[str, Any] | Codecs | None = None, arrays: str = "base64"
) -> Any:
    """``value`` as data: JSON scalars as they are (non-finite floats tagged), lists, and
    ``{"$t": tag, ...}`` for tuples, dicts, NumPy arrays and scalars (``arrays="native"``: kept as
    they are, with bytes, complex numbers and sets) and for a value of a class a port type stores
    (``{"$t": "port", "type": name, "v": its encode(value), encoded}``). Raises
    :class:`StorageError` for anything else."""
    return _encode(value, where, codecs_of(codecs), arrays == "native")


def _encode(value: Any, where: str, codecs: Codecs, native: bool) -> Any:
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, np.ndarray):
        if value.dtype.kind not in "biufc" or value.dtype.hasobject:
            raise StorageError(f"{where}: an array of dtype {value.dtype} cannot be stored")
        if native:
            return value
        arr = np.ascontiguousarray(value)
        return {
            "$t": "ndarray",
            "dtype": arr.dtype.str,
            "shape": list(arr.shape),
            "data": base64.b64encode(arr.tobytes()).decode("ascii"),
        }
    if isinstance(value, np.generic):
        if value.dtype.kind not in "biufc":
            raise StorageError(f"{where}: a numpy scalar of dtype {value.dtype} cannot be stored")
        if native:
            return value
        return {
            "$t": "scalar",
            "dtype": value.dtype.str,
            "data": base64.b64encode(value.tobytes()).decode("ascii"),
        }
    if isinstance(value, int):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) or native else {"$t": "float", "v": repr(value)}
    if native and isinstance(value, _NATIVE):
        return value
    if isinstance(value, list):
        return [_encode(v, f"{where}[{i}]", codecs, native) for i, v in enumerate(value)]
    if isinstance(value, tuple):
        return {
            "$t": "tuple",
            "v": [_encode(v, f"{where}[{i}]", codecs, native) for i, v in enumerate(value)],
        }
    if isinstance(value, dict):
        return {
            "$t": "dict",
            "v": [
                [_encode(k, f"{where} key", codecs, native), _encode(v, f"{where}[{k!r}]", codecs, native)]
                for k, v in value.items()
            ],
        }
    pt = codecs.by_class.get(type(value))
    if pt is not None:
        try:
            data = pt.encode(value)
        except StorageError as exc:
            raise StorageError(f"{where}: {exc}") from None
        except Exception as exc:  # noqa: BLE001 - a plugin's encode: located
            raise StorageError(
                f"{where}: port type {pt.name!r}'s encode raised {type(exc).__name__}: {str(exc)[:80]}"
            ) from exc
        return {"$t": "port", "type": pt.name, "v": _encode(data, f"{where} ({pt.name})", codecs, native)}
    raise StorageError(
        f"{where}: a {type(value).__module__}.{type(value).__qualname__} cannot be stored "
        "(no registered port type stores it: see PortType.stores)"
    )


# --------------------------------------------------------------------------- decoding
def decode_value(data: Any, where: str = "value", codecs: Mapping[str, Any] | Codecs | None = None) -> Any:
    """The inverse of :func:`encode_value`; anything it would not have written raises
    :class:`StorageError` naming ``where``. Only data and the registered port types' values (by
    their own ``decode``) are ever built."""
    return _decode(data, where, codecs_of(codecs))


def _decode(data: Any, where: str, codecs: Codecs) -> Any:
    if data is None or isinstance(data, (bool, str, int, float)):
        return data
    if isinstance(data, (np.ndarray, np.generic, *_NATIVE)):  # only from the cache's pickle
        return data
    if isinstance(data, list):
        return [_decode(v, f"{where}[{i}]", codecs) for i, v in enumerate(data)]
    if not isinstance(data, dict) or not isinstance(data.get("$t"), str):
        raise StorageError(
            f"{where}: expected a JSON scalar, a list or a tagged object {{'$t': ...}}, got {str(data)[:80]}"
        )
    tag = data["$t"]
    decode = _DECODERS.get(tag)
    if decode is None:
        raise StorageError(f"{where}: unknown value type {tag!r} (known tags: {', '.join(_DECODERS)})")
    try:
        return decode(data, where, codecs)
    except StorageError:
        raise
    except (KeyError, TypeError, ValueError) as exc:
        raise StorageError(f"{where}: malformed {tag!r} value ({type(exc).__name__}: {exc})") from None


def _decode_float(data: dict[str, Any], where: str, codecs: Codecs) -> float:
    if data["v"] not in ("nan", "inf", "-inf"):
        raise StorageError(f"{where}: expected 'nan', 'inf' or '-inf', got {data['v']!r}")
    return float(data["v"])


def _list(v: Any, where: str) -> list:
    if not isinstance(v, list):
        raise StorageError(f"{where}: expected a list")
    return v


def _decode_tuple(data: dict[str, Any], where: str, codecs: Codecs) -> tuple:
    return tuple(_decode(v, f"{where}[{i}]", codecs) for i, v in enumerate(_list(data["v"], where)))


def _decode_dict(data: dict[str, Any], where: str, codecs: Codecs) -> dict:
    out = {}
    for i, item in enumerate(_list(data["v"], where)):
        if not (isinstance(item, list) and len(item) == 2):
            raise StorageError(f"{where}[{i}]: expected a [key, value] pair")
        key = _decode(item[0], f"{where} key", codecs)
        try:
            hash(key)
        except TypeError:
            raise StorageError(f"{where}: a dict key must be hashable, got {str(key)[:60]}") from None
        out[key] = _decode(item[1], f"{where}[{key!r}]", codecs)
    return out


def dtype_of(text: Any, where: str) -> np.dtype:
    """A numeric NumPy dtype from its type string (``'<f4'``); anything else is refused."""
    if not isinstance(text, str) or len(text) > 8:
        raise StorageError(
            f"{where}: dtype: expected a numpy type string such as '<f4', got {str(text)[:40]}"
        )
    try:
        dt = np.dtype(text)
    except TypeError:
        raise StorageError(f"{where}: dtype: not a numpy type: {text!r}") from None
    if dt.kind not in "biufc" or dt.hasobject:
        raise StorageError(f"{where}: dtype {text!r}: only numbers and booleans are stored")
    return dt


def shape_of(shape: Any, where: str) -> list[int]:
    """An array shape: at most :data:`MAX_NDIM` integers in ``[0, MAX_DIM]``, checked before
    anything is allocated."""
    if not (
        isinstance(shape, list)
        and len(shape) <= MAX_NDIM
        and all(isinstance(n, int) and not isinstance(n, bool) and 0 <= n <= MAX_DIM for n in shape)
    ):
        raise StorageError(
            f"{where}: shape: expected a list of at most {MAX_NDIM} integers in 0..{MAX_DIM}, got {str(shape)[:60]}"
        )
    return shape


def _decode_ndarray(data: dict[str, Any], where: str, codecs: Codecs) -> np.ndarray:
    dtype = dtype_of(data["dtype"], where)
    shape = shape_of(data["shape"], where)
    size = math.prod(shape) * dtype.itemsize  # Python integers: no overflow, nothing allocated yet
    text = data["data"]
    if not isinstance(text, str):
        raise StorageError(f"{where}: data: expected a base64 string")
    if size > MAX_BYTES or len(text) != 4 * ((size + 2) // 3):
        raise StorageError(
            f"{where}: {len(text)} base64 characters of data do not make an array of shape {shape} and dtype {dtype}"
        )
    raw = base64.b64decode(text, validate=True)
    if len(raw) != size:
        raise StorageError(
            f"{where}: {len(raw)} bytes of data do not make an array of shape {shape} and dtype {dtype}"
        )
    return np.frombuffer(raw, dtype=dtype).reshape(shape).copy()


def _decode_scalar(data: dict[str, Any], where: str, codecs: Codecs) -> np.generic:
    dtype = dtype_of(data["dtype"], where)
    raw = base64.b64decode(data["data"], validate=True)
    if len(raw) != dtype.itemsize:
        raise StorageError(f"{where}: {len(raw)} bytes of data are not one {dtype}")
    return np.frombuffer(raw, dtype=dtype)[0]


def _decode_port(data: dict[str, Any], where: str, codecs: Codecs) -> Any:
    name = data["type"]
    pt = codecs.by_name.get(name) if isinstance(name, str) else None
    if pt is None:
        known = ", ".join(sorted(codecs.by_name)) or "(none)"
        raise StorageError(
            f"{where}: a value of port type {str(name)[:40]!r}, which no installed plugin stores (stored types: {known})"
        )
    inner = _decode(data["v"], f"{where} ({name})", codecs)
    try:
        value = pt.decode(inner)
    except StorageError as exc:
        raise StorageError(f"{where}: {exc}") from None
    except Exception as exc:  # noqa: BLE001 - a plugin's decode refusing malformed data: located
        raise StorageError(
            f"{where}: port type {name!r} cannot decode it ({type(exc).__name__}: {str(exc)[:80]})"
        ) from None
    if type(value) is not pt.stores:
        raise StorageError(
            f"{where}: port type {name!r}'s decode returned a {type(value).__name__}, not a {pt.stores.__name__}"
        )
    return value


#: how each tag of :func:`encode_value` is decoded
_DECODERS: dict[str, Callable[[dict[str, Any], str, Codecs], Any]] = {
    "float": _decode_float,
    "tuple": _decode_tuple,
    "dict": _decode_dict,
    "ndarray": _decode_ndarray,
    "scalar": _decode_scalar,
    "port": _decode_port,
}
