"""Reading a TOML table against a schema: every file format of the project is declared once, as msgspec structs
(types, defaults, bounds, choices, descriptions), and read through :func:`read_table`, whose errors name the
file, the key path and what was expected, with a "did you mean" for a mistyped key::

    configs/x.toml: [axes.light].max_deg: expected a number, got "high"
    configs/x.toml: [bench].transprt: unknown key; did you mean 'transport'?

Bounds come from the fields' ``msgspec.Meta`` (``ge``, ``gt``, ``le``, ``lt``: "must lie in [lo, hi], got v");
a field may give its own check in ``Meta(extra={"check": f})`` (``f(value) -> error text or None``) and its own
wording of the expected type in ``Meta(extra={"expected": "..."})``. :func:`json_schema` turns a struct into
the JSON Schema that TOML editors use to complete and check a file (``docs/schema/*.json``).
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Callable, Mapping
from typing import Any

import msgspec
import msgspec.inspect as mi

__all__ = ["SchemaError", "describe", "Table", "read_table", "fields_of", "json_schema"]


class SchemaError(ValueError):
    """A value of a file does not fit its schema; the message names the file, the key path and what was
    expected."""


def describe(v: Any) -> str:
    """A value as a message shows it: strings quoted (long ones cut), tables as "a table", TOML booleans."""
    if isinstance(v, str):
        return f'"{v}"' if len(v) <= 60 else f'"{v[:40]}..." ({len(v)} characters)'
    if isinstance(v, dict):
        return "a table"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int) and abs(v) >= 10**15:
        return f"{v:.6g}"  # not 300 digits
    if isinstance(v, list) and len(repr(v)) > 80:
        return repr(v)[:60] + f"... ({len(v)} items)"
    return repr(v)


def _is_num(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _finite_num(v: Any) -> bool:
    return _is_num(v) and math.isfinite(float(v))


def _unwrap(t: Any) -> tuple[Any, dict[str, Any]]:
    """(type without Metadata and without ``| None``, the field's ``extra``)."""
    extra: dict[str, Any] = {}
    while True:
        if isinstance(t, mi.Metadata):
            extra = {**(t.extra or {}), **extra}
            t = t.type
        elif isinstance(t, mi.UnionType) and any(isinstance(x, mi.NoneType) for x in t.types):
            rest = tuple(x for x in t.types if not isinstance(x, mi.NoneType))
            t = rest[0] if len(rest) == 1 else mi.UnionType(rest)
        else:
            return t, extra


def _bounds_error(t: Any, v: float) -> str | None:
    ge, gt, le, lt = (getattr(t, k, None) for k in ("ge", "gt", "le", "lt"))
    lo, hi = (ge if ge is not None else gt), (le if le is not None else lt)
    ok = ((ge is None or v >= ge) and (gt is None or v > gt) and (le is None or v <= le) and (lt is None or v < lt))
    if ok:
        return None
    if lo is not None and hi is not None:
        return (f"must lie in {'[' if ge is not None else '('}{lo:g}, {hi:g}{']' if le is not None else ')'}, "
                f"got {v:g}")
    if lo is not None:
        return f"must be {'>=' if ge is not None else '>'} {lo:g}, got {v:g}"
    return f"must be {'<=' if le is not None else '<'} {hi:g}, got {v:g}"


def convert(t: Any, v: Any) -> tuple[Any, str | None]:
    """``v`` (a TOML value) as the msgspec type ``t``: (value, None) or (None, what was expected)."""
    t, extra = _unwrap(t)
    expected = extra.get("expected")
    out: Any
    if isinstance(t, mi.BoolType):
        if not isinstance(v, bool):
            return None, f"expected {expected or 'true or false'}, got {describe(v)}"
        out = v
    elif isinstance(t, mi.IntType):
        if isinstance(v, int) and not isinstance(v, bool):
            out = v
        elif isinstance(v, float) and v.is_integer():
            out = int(v)
        else:
            return None, f"expected {expected or 'an integer'}, got {describe(v)}"
    elif isinstance(t, mi.FloatType):
        if not _is_num(v):
            return None, f"expected {expected or 'a number'}, got {describe(v)}"
        if not math.isfinite(float(v)):
            return None, f"expected a finite number, got {describe(v)}"
        out = float(v)
    elif isinstance(t, mi.StrType):
        if not isinstance(v, str):
            return None, f"expected {expected or 'a string'}, got {describe(v)}"
        out = v
    elif isinstance(t, mi.LiteralType):  # choices: first the type of the choices, then the choice
        base = mi.IntType() if all(isinstance(x, int) for x in t.values) else mi.StrType()
        out, err = convert(base, v)
        if err is not None:
            return None, err
        if out not in t.values:
            return None, f"expected one of {', '.join(map(describe, t.values))}, got {describe(out)}"
    elif isinstance(t, mi.UnionType):  # e.g. int | str: the first member that takes it (ints must be ints)
        for member in t.types:
            if isinstance(member, mi.IntType) and not (isinstance(v, int) and not isinstance(v, bool)):
                continue
            got, err = convert(member, v)
            if err is None:
                out = got
                break
        else:
            return None, f"expected {expected or ' or '.join(type(m).__name__ for m in t.types)}, got {describe(v)}"
    elif isinstance(t, (mi.ListType, mi.VarTupleType)):
        item, _ = _unwrap(t.item_type)
        if isinstance(item, mi.TupleType):  # points: pairs of numbers
            what = expected or "[theta_i_deg, theta_o_deg] pairs"
            if not isinstance(v, list) or not v:
                return None, f"expected a non-empty list of {what}, got {describe(v)}"
            for p in v:
                if not (isinstance(p, list) and len(p) == len(item.item_types) and all(_finite_num(x) for x in p)):
                    return None, f"expected {what}, got {describe(p)}"
            out = [tuple(float(x) for x in p) for p in v]
            if isinstance(t, mi.VarTupleType):
                out = tuple(out)
        elif isinstance(item, mi.FloatType):
            if not isinstance(v, list) or not v:
                return None, f"expected {expected or 'a non-empty list of numbers'}, got {describe(v)}"
            if not all(_finite_num(x) for x in v):
                return None, f"expected a list of numbers, got {describe(v)}"
            out = [float(x) for x in v]
            if isinstance(t, mi.VarTupleType):
                out = tuple(out)
        else:
            if not isinstance(v, list):
                return None, f"expected {expected or 'a list'}, got {describe(v)}"
            out = []
            for x in v:
                got, err = convert(item, x)
                if err is not None:
                    return None, err
                out.append(got)
    else:  # pragma: no cover - a schema type without a reader
        raise AssertionError(f"no reader for {t!r}")
    check: Callable[[Any], str | None] | None = extra.get("check")
    if check is not None:  # the field's own check (and wording) instead of the generic bounds
        err = check(out)
    elif isinstance(out, (int, float)) and not isinstance(out, bool):
        err = _bounds_error(t, out)
    else:
        err = None
    return (None, err) if err is not None else (out, None)


def fields_of(cls: type) -> tuple[Any, ...]:
    """The fields of the struct ``cls`` (msgspec.inspect), cached."""
    f = _FIELDS.get(cls)
    if f is None:
        f = _FIELDS[cls] = mi.type_info(cls).fields
    return f


_FIELDS: dict[type, tuple[Any, ...]] = {}


class Table:
    """One TOML table read against the struct ``cls``: ``t[key]`` (the value, or the field's default),
    :meth:`given`, and :meth:`error` for checks that need several keys. ``strict``: unknown keys and missing
    required keys are errors (else unknown keys are ignored and missing ones are ``defaults[key]``); ``skip``:
    keys that are sub-tables read on their own."""

    def __init__(self, source: str, section: str, raw: Any, cls: type, *, strict: bool = True,
                 defaults: Mapping[str, Any] | None = None, skip: tuple[str, ...] = ()) -> None:
        self.source, self.section, self.cls = source, section, cls
        if not isinstance(raw, Mapping):
            raise SchemaError(f"{source}: [{section}]: expected a table, got {describe(raw)}")
        self.raw = dict(raw)
        flds = fields_of(cls)
        names = [f.encode_name for f in flds] + list(skip)
        if strict:
            unknown = [k for k in self.raw if k not in names]
            if unknown:
                k = unknown[0]
                near = difflib.get_close_matches(k, names, n=1)
                hint = f"; did you mean {near[0]!r}?" if near else f"; allowed keys: {', '.join(names)}"
                raise SchemaError(f"{source}: [{section}].{k}: unknown key{hint}")
        self.values: dict[str, Any] = {}
        for f in flds:
            k = f.encode_name
            if k in skip:
                continue
            if k not in self.raw:
                if defaults is not None and k in defaults:
                    self.values[k] = defaults[k]
                elif f.required:
                    if strict:
                        raise SchemaError(f"{source}: [{section}].{k}: missing key (required)")
                    self.values[k] = None
                else:
                    self.values[k] = f.default if f.default is not msgspec.NODEFAULT else f.default_factory()
                continue
            v, err = convert(f.type, self.raw[k])
            if err is not None:
                raise SchemaError(f"{source}: [{section}].{k}: {err}")
            self.values[k] = v

    def __getitem__(self, key: str) -> Any:
        return self.values[key]

    def given(self, key: str) -> bool:
        return key in self.raw

    def error(self, key: str, text: str) -> SchemaError:
        return SchemaError(f"{self.source}: [{self.section}].{key}: {text}")

    def build(self, **extra: Any) -> Any:
        """The struct itself, from the values read (``extra``: fields set directly)."""
        return self.cls(**{**{f.name: self.values[f.encode_name] for f in fields_of(self.cls)
                              if f.encode_name in self.values}, **extra})


def read_table(source: str, section: str, raw: Any, cls: type, **kw: Any) -> Table:
    """:class:`Table` (the reader of one table)."""
    return Table(source, section, raw, cls, **kw)


def _no_null(node: Any) -> Any:
    """TOML has no null: an absent key is what None means, so the schema offers no ``null``."""
    if isinstance(node, dict):
        out = {k: _no_null(v) for k, v in node.items() if not (k == "default" and v is None)}
        alts = out.get("anyOf")
        if isinstance(alts, list):
            rest = [a for a in alts if a != {"type": "null"}]
            if len(rest) == 1:
                del out["anyOf"]
                out = {**rest[0], **out}
            else:
                out["anyOf"] = rest
        return out
    if isinstance(node, list):
        return [_no_null(x) for x in node]
    return node


def json_schema(cls: type, title: str, description: str) -> dict[str, Any]:
    """The JSON Schema (draft 2020-12) of the struct ``cls``, for editors."""
    schema = _no_null(msgspec.json.schema(cls))
    ref = schema.pop("$ref", None)
    defs = schema.pop("$defs", {})
    root = defs.pop(ref.rsplit("/", 1)[-1]) if ref else schema
    out = {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": title, "description": description,
           **{k: v for k, v in root.items() if k != "title"}}
    if defs:
        out["$defs"] = defs
    return out
