"""What a reconstruction method is and where it is registered: one options struct per method, declared once.

A method is a :class:`Method`: a name, a one-line summary, a ``reconstruct(slice, options, context)`` function
and its ``options``, one :mod:`msgspec` struct whose fields carry their types, defaults, bounds (``Meta(ge=...,
le=...)``) and descriptions. Everything else is made from that declaration (:class:`OptionSpec`):

* the common :class:`Options` a run carries (one attribute per option, ``<method>_<field>`` such as
  ``prior_anchor``, unless the field names another such as ``revolve_axis``; its default the field's);
* ``gonio-reconstruct``'s flag (``--<method>-<field>`` unless it names another, or none: ``flag=None``), its
  ``--help`` text (the description), its choices and the one-line error of a value out of bounds
  (:mod:`reconstruction.methods.flags`);
* the JSON Schema ``docs/schema/method-options.json`` (:func:`options_schema`);
* the check of a value given from Python (:meth:`Method.options_from`: "method prior: --prior-anchor 1.5:
  expected ...").

:func:`option` writes the ``Meta`` of a field with its flag's name, metavar and the wording of its bounds; a plain
``msgspec.Meta(ge=..., le=..., description=...)`` works as well. Adding a method is its module and one
:func:`register` line (``reconstruction/methods/__init__.py`` registers the built-in ones).
"""

from __future__ import annotations

import functools
import math
import types
import typing
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Annotated, Any, Literal, Union

import msgspec
from msgspec import Meta

from reconstruction.base import Reconstruction, ReconstructionError
from reconstruction.core.scene import Scene
from reconstruction.core.slicedata import Slice

__all__ = ["Method", "Context", "Options", "OptionSpec", "NoOptions", "option", "REGISTRY", "register", "get",
           "names", "option_specs", "options_schema", "DEFAULT_FLAG"]

#: ``option(flag=DEFAULT_FLAG)``: the flag ``--<method>-<field>`` (the default).
DEFAULT_FLAG = "<method>-<field>"


def option(description: str, *, flag: str | None = DEFAULT_FLAG, attr: str | None = None,
           metavar: str | None = None, expected: str | None = None, repeat: bool = False,
           ge: float | None = None, le: float | None = None, gt: float | None = None,
           lt: float | None = None) -> Meta:
    """The ``Meta`` of one option: its description (the ``--help`` text and the schema's), its bounds, and how the
    command line and :class:`Options` name it.

    ``flag``: the command line's flag (default ``--<method>-<field>``; None: an option for Python callers only);
    ``attr``: the attribute of :class:`Options` (default ``<method>_<field>``); ``metavar``: its value's name in
    ``--help``; ``expected``: what a value out of bounds is told it should be (default from the bounds, e.g. "a
    number from 0 to 1"); ``repeat``: the flag may be given several times, its values joined with ``os.pathsep``.
    """
    extra = {k: v for k, v in (("flag", flag), ("attr", attr), ("metavar", metavar), ("expected", expected),
                               ("repeat", repeat)) if v is not None and v is not False and v != DEFAULT_FLAG}
    if flag is None:
        extra["flag"] = None
    return Meta(ge=ge, le=le, gt=gt, lt=lt, description=description, extra=extra or None)


class NoOptions(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """A method without options of its own."""


@dataclass(frozen=True)
class OptionSpec:
    """One declared option of one method, as every face of it sees it (made by :func:`option_specs`)."""

    method: str
    key: str  # the struct's field: the key of docs/schema/method-options.json and of a study's or script's table
    attr: str  # the attribute of Options
    flag: str | None  # gonio-reconstruct's flag, or None
    help: str
    default: Any
    kind: str  # "number", "integer", "choice", "text", "list" or "switch" (a bool: the flag sets it)
    choices: tuple[Any, ...] | None = None
    bounds: tuple[tuple[str, float], ...] = ()  # (("ge", 0.0), ("le", 1.0)): msgspec's names
    metavar: str | None = None
    expected: str | None = None
    repeat: bool = False
    optional: bool = False

    @property
    def dest(self) -> str | None:
        """The flag's argparse destination (``--prior-anchor`` -> ``prior_anchor``), or None without a flag."""
        return self.flag.lstrip("-").replace("-", "_") if self.flag else None

    def bounds_text(self) -> str:
        """What the bounds ask, in the command line's words: "a number from 0 to 1", "an integer >= 0"."""
        b = dict(self.bounds)
        noun = "an integer" if self.kind == "integer" else "a number"
        if self.kind == "integer" and b == {"ge": 1}:
            return "a positive integer"
        if "ge" in b and "le" in b:
            return f"{noun} from {b['ge']:g} to {b['le']:g}"
        words = {"ge": ">=", "gt": ">", "le": "<=", "lt": "<"}
        return f"{noun} " + " and ".join(f"{words[k]} {v:g}" for k, v in self.bounds) if b else noun

    def within(self, value: Any) -> bool:
        """Whether a number ``value`` is within the bounds (a value that is not a number: True, the schema says)."""
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return True
        if not math.isfinite(value):
            return False
        return all({"ge": value >= v, "gt": value > v, "le": value <= v, "lt": value < v}[k] for k, v in self.bounds)

    def out_of_bounds(self, value: Any) -> str:
        """The one line a value out of bounds gets (from Python; the command line words it as argparse does)."""
        shown = f"{value:g}" if isinstance(value, (int, float)) else repr(value)
        return f"method {self.method}: {self.flag or self.key} {shown}: expected {self.expected or self.bounds_text()}"


def _unwrap(hint: Any) -> tuple[Any, list[Meta], bool]:
    """(the bare type, the Meta objects around it, whether None is allowed) of a field's annotation."""
    metas: list[Meta] = []
    optional = False
    while True:
        origin = typing.get_origin(hint)
        if origin is Annotated:
            args = typing.get_args(hint)
            hint, metas = args[0], metas + [m for m in args[1:] if isinstance(m, Meta)]
        elif origin in (Union, types.UnionType):
            rest = [a for a in typing.get_args(hint) if a is not type(None)]
            optional = optional or len(rest) < len(typing.get_args(hint))
            if len(rest) != 1:
                return hint, metas, optional
            hint = rest[0]
        else:
            return hint, metas, optional


def _kind(method: str, key: str, hint: Any, flag: str | None) -> tuple[str, tuple[Any, ...] | None]:
    origin = typing.get_origin(hint)
    if hint is bool:
        return "switch", None
    if hint is float:
        return "number", None
    if hint is int:
        return "integer", None
    if hint is str:
        return "text", None
    if origin is Literal:
        return "choice", typing.get_args(hint)
    if origin in (list, tuple):
        item, _, _ = _unwrap(typing.get_args(hint)[0])
        return "list", typing.get_args(item) if typing.get_origin(item) is Literal else None
    if not flag:
        return "other", None
    raise TypeError(f"method {method}: option {key}: a {hint!r} has no command-line form; declare it with "
                    "flag=None or as a number, text, a Literal, a list or a bool")


@functools.cache
def struct_specs(method: str, options: type[msgspec.Struct]) -> tuple[OptionSpec, ...]:
    """The :class:`OptionSpec` of every field of ``options`` (the struct of ``method``), in declaration order."""
    hints = typing.get_type_hints(options, include_extras=True)
    defaults = dict(zip(options.__struct_fields__, (None,) * len(options.__struct_fields__), strict=True))
    n_req = len(options.__struct_fields__) - len(options.__struct_defaults__)
    for key, d in zip(options.__struct_fields__[n_req:], options.__struct_defaults__, strict=True):
        factory = getattr(d, "factory", None)
        defaults[key] = factory() if factory is not None else d
    out = []
    for key in options.__struct_fields__:
        hint, metas, optional = _unwrap(hints[key])
        extra: dict[str, Any] = {}
        bounds: list[tuple[str, float]] = []
        help_ = ""
        for m in metas:
            extra.update(m.extra or {})
            help_ = m.description or help_
            bounds += [(b, getattr(m, b)) for b in ("ge", "gt", "le", "lt") if getattr(m, b) is not None]
        flag = extra.get("flag", f"--{method}-{key}".replace("_", "-"))
        kind, choices = _kind(method, key, hint, flag)
        if kind == "switch" and defaults[key] is not False:
            raise TypeError(f"method {method}: option {key}: a flag sets a bool option, so its default must be False")
        out.append(OptionSpec(method, key, extra.get("attr", f"{method}_{key}"), flag, help_, defaults[key], kind,
                              choices, tuple(bounds), extra.get("metavar"), extra.get("expected"),
                              bool(extra.get("repeat")), optional))
    return tuple(out)


@dataclass(frozen=True)
class Context:
    """What a method is given beside its own options: the scene (common to every method), a progress callback,
    and the run's :class:`Options` (every method's options: a method that builds another, as ``prior`` its
    anchor's ``bivariate``, builds it with them)."""

    scene: Scene | None
    progress: Callable[[str], None] | None
    options: Options


@dataclass(frozen=True)
class Method:
    """One reconstruction method: ``reconstruct(slice, options, context)`` -> Reconstruction, where ``options``
    is an instance of the struct ``options`` (validated) and ``context`` a :class:`Context`.

    ``build(slice, opts, progress)`` is what the pipeline and ``auto`` call: by default ``reconstruct`` with this
    method's options taken from the run's :class:`Options` (a test may give its own ``build`` instead of
    ``reconstruct``). ``available``: None (always usable) or whether ``auto`` may try it with the run's
    :class:`Options` (``prior`` needs a folder); ``modules``: the modules ``reconstruct`` imports (scipy's among
    them), which a run that builds it may import ahead (:func:`reconstruction.methods.auto.import_methods`, while
    its forked child works).
    """

    name: str
    summary: str
    build: Callable[[Slice, Options | None, Callable[[str], None] | None], Reconstruction] = field(
        default=None, compare=False, repr=False)  # type: ignore[assignment]
    options: type[msgspec.Struct] = NoOptions
    available: Callable[[Options], bool] | None = None
    modules: tuple[str, ...] = ()
    reconstruct: Callable[[Slice, Any, Context], Reconstruction] | None = None

    def __post_init__(self) -> None:
        if self.build is None or getattr(self.build, "__func__", None) is Method._build:  # (also after replace())
            if self.reconstruct is None:
                raise ValueError(f"method {self.name}: give its reconstruct function")
            object.__setattr__(self, "build", self._build)

    @property
    def specs(self) -> tuple[OptionSpec, ...]:
        """The declaration of each of this method's options."""
        return struct_specs(self.name, self.options)

    @property
    def common(self) -> dict[str, str]:
        """{field of the options struct: the attribute of :class:`Options` that carries it}."""
        return {s.key: s.attr for s in self.specs}

    def usable(self, opts: Options) -> bool:
        """Whether this method can run with ``opts`` (``auto`` skips the others, e.g. ``prior`` without --prior)."""
        return self.available is None or self.available(opts)

    def options_from(self, opts: Options) -> Any:
        """This method's options, taken from the common ``opts`` (an option they do not carry: its declared default)
        and validated against its struct."""
        return self.parse_options({s.key: getattr(opts, s.attr, s.default) for s in self.specs})

    def parse_options(self, raw: Mapping[str, Any]) -> Any:
        """Validate ``raw`` (e.g. a table of a study or a script) against the method's struct; a value out of its
        bounds is :class:`ReconstructionError` "method NAME: FLAG VALUE: expected ...", anything else
        :class:`ReconstructionError` naming the method and msgspec's path of the option."""
        for spec in self.specs:
            if spec.key in raw and not spec.within(raw[spec.key]):
                raise ReconstructionError(spec.out_of_bounds(raw[spec.key]))
        try:
            return msgspec.convert(dict(raw), self.options)
        except msgspec.ValidationError as e:
            raise ReconstructionError(f"method {self.name}: options: {e}") from None

    def _build(self, s: Slice, opts: Options | None = None,
               progress: Callable[[str], None] | None = None) -> Reconstruction:
        """The reconstruction of ``s`` with the run's options ``opts`` (this method's own taken from them)."""
        opts = opts if opts is not None else Options()
        assert self.reconstruct is not None
        return self.reconstruct(s, self.options_from(opts), Context(opts.scene, progress, opts))


REGISTRY: dict[str, Method] = {}


def option_specs() -> Iterator[OptionSpec]:
    """Every registered method's options, in registration order (an option two methods share comes twice)."""
    for m in REGISTRY.values():
        yield from m.specs


def _same(a: OptionSpec, b: OptionSpec) -> bool:
    return (a.attr, a.flag, a.default, a.kind, a.choices, a.bounds) == (b.attr, b.flag, b.default, b.kind, b.choices,
                                                                        b.bounds)


def register(method: Method) -> Method:
    """Add ``method`` to :data:`REGISTRY`. Its name must be new, and an option it shares with another method (the
    same flag or :class:`Options` attribute) must be declared alike: ValueError otherwise."""
    if method.name in REGISTRY or method.name == "auto":
        raise ValueError(f"a method named {method.name!r} is already registered")
    known = list(option_specs())
    for spec in method.specs:
        if spec.attr in ("scene", "replace") or spec.attr.startswith("_"):
            raise ValueError(f"method {method.name}: option {spec.key}: {spec.attr!r} is not a name Options can carry")
        for k in known:
            if (k.attr == spec.attr or (spec.flag and k.flag == spec.flag)) and not _same(k, spec):
                raise ValueError(f"method {method.name}: option {spec.key} ({spec.flag or spec.attr}) is declared "
                                 f"differently by method {k.method} ({k.key}): give it another name")
    REGISTRY[method.name] = method
    return method


def get(name: str) -> Method:
    """The registered method ``name``; :class:`ReconstructionError` naming the choices otherwise."""
    try:
        return REGISTRY[name]
    except KeyError:
        raise ReconstructionError(f"unknown method {name!r}; expected one of auto, {', '.join(REGISTRY)}") from None


def names() -> tuple[str, ...]:
    """Registered method names, in registration order."""
    return tuple(REGISTRY)


def _defaults() -> dict[str, Any]:
    return {s.attr: s.default for s in option_specs()}


class Options:
    """The options of one run: ``scene`` (common to every method) and every registered method's options, each as
    the attribute its declaration names (``fill``, ``lobes``, ``revolve_axis``, ``revolve_smoothing``,
    ``cos_power``, ``prior``, ``prior_anchor``, ``prior_near``, ``prior_exclude``, ...), defaulting to the
    declared default. ``Options(prior="dir", prior_anchor=0.25)``; an unknown name is a TypeError.
    """

    def __init__(self, scene: Scene | None = None, **values: Any) -> None:
        defaults = _defaults()
        unknown = sorted(set(values) - set(defaults))
        if unknown:
            raise TypeError(f"Options: unknown option(s) {', '.join(unknown)}; the registered methods declare "
                            f"scene, {', '.join(defaults)}")
        self.scene = scene
        self._values = {**defaults, **values}

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_"):
            raise AttributeError(name)
        values = self.__dict__.get("_values", {})
        if name in values:
            return values[name]
        defaults = _defaults()  # a method registered after these options were made: its default
        if name in defaults:
            return defaults[name]
        raise AttributeError(f"Options has no option {name!r}")

    def replace(self, **changes: Any) -> Options:
        """A copy with ``changes`` (as :func:`dataclasses.replace`)."""
        scene = changes.pop("scene", self.scene)
        return Options(scene, **{**self._values, **changes})

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Options) and (self.scene, self._values) == (other.scene, other._values)

    def __repr__(self) -> str:
        return "Options(" + ", ".join(f"{k}={v!r}" for k, v in {"scene": self.scene, **self._values}.items()) + ")"


def options_schema() -> dict[str, Any]:
    """JSON Schema of every registered method's options (``docs/schema/method-options.json``): each option's
    description names its flag."""
    _, defs = msgspec.json.schema_components([m.options for m in REGISTRY.values()],
                                             ref_template="#/$defs/{name}")
    for m in REGISTRY.values():
        props = defs[m.options.__name__].get("properties", {})
        for spec in m.specs:
            p = props[spec.key]
            inner = next((a for a in p.get("anyOf", ()) if "description" in a), None)
            if inner is not None:  # an Optional field's description sits in its non-null branch: lift it
                p["description"] = inner.pop("description")
            if spec.flag and spec.help:
                p["description"] = f"{spec.help} ({spec.flag})"
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": "gonio-brdf method options",
            "description": "The options of each reconstruction method (reconstruction.methods), by method name.",
            "type": "object", "additionalProperties": False,
            "properties": {m.name: {"$ref": f"#/$defs/{m.options.__name__}", "description": m.summary}
                           for m in REGISTRY.values()}, "$defs": defs}
