"""The command line's face of the methods' declared options: one ``gonio-reconstruct`` flag per option that
declares one (its ``--help`` text, choices, metavar and the one-line error of a value out of bounds, all from the
option's declaration, :mod:`reconstruction.methods.registry`), and the values a parsed command line gives them.

An option two methods share (``--fill``: revolve and bivariate) is one flag. A value out of bounds is a usage
error of exit status 2 naming the flag: ``argument --prior-anchor: expected a number from 0 to 1, got '2'``.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Callable
from typing import Any

from reconstruction.methods.registry import OptionSpec, option_specs

__all__ = ["add_arguments", "flag_specs", "values"]


def flag_specs() -> list[OptionSpec]:
    """The registered options that have a flag, one per flag, in registration order."""
    seen: dict[str, OptionSpec] = {}
    for spec in option_specs():
        if spec.flag and spec.flag not in seen:
            seen[spec.flag] = spec
    return list(seen.values())


def _number(spec: OptionSpec) -> Callable[[str], Any]:
    """An argparse ``type`` for a number option: the number within its declared bounds."""
    cast: Callable[[str], Any] = int if spec.kind == "integer" else float

    def parse(text: str) -> Any:
        try:
            v = cast(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {spec.bounds_text()}, got {text!r}") from None
        if not spec.within(v):
            raise argparse.ArgumentTypeError(f"expected {spec.bounds_text()}, got {text!r}")
        return v

    return parse


def _items(text: str) -> tuple[str, ...]:
    """A comma-separated list (``--lobes lambert,ggx``), blanks dropped; its items are checked where used."""
    return tuple(x.strip() for x in text.split(",") if x.strip())


def add_arguments(ap: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    """Add a flag for every registered option that declares one."""
    for spec in flag_specs():
        kw: dict[str, Any] = {"help": spec.help.replace("%", "%%"), "dest": spec.dest}
        assert spec.flag is not None
        if spec.kind == "switch":
            ap.add_argument(spec.flag, action="store_true", **kw)
            continue
        if spec.metavar:
            kw["metavar"] = spec.metavar
        if spec.kind in ("number", "integer"):
            kw["type"] = _number(spec)
        elif spec.kind == "choice":
            kw["choices"] = spec.choices
        elif spec.kind == "list":
            kw["type"] = _items
        if spec.repeat:
            kw["action"] = "append"
        kw["default"] = None if spec.repeat or spec.kind == "list" else spec.default
        ap.add_argument(spec.flag, **kw)


def values(args: argparse.Namespace) -> list[tuple[OptionSpec, Any]]:
    """(option, value) of every flag of a parsed command line (a repeated flag's values joined with
    ``os.pathsep``; a flag the parser did not have: its declared default)."""
    out = []
    for spec in flag_specs():
        v = getattr(args, spec.dest or "", spec.default)
        if spec.repeat and isinstance(v, list):
            v = os.pathsep.join(v)
        out.append((spec, v))
    return out
