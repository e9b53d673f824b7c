"""Parameter declarations: a field's default, meaning and valid range in one place (`param`, `choice`), from which
validation, the node's ROS parameter descriptors and the README's tables are derived. The bottom layer: it imports
nothing of the project, so every package may declare settings with it."""
from __future__ import annotations

import difflib
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from numbers import Integral, Real
from typing import Any


class ConfigError(ValueError):
    """A parameter value the engine refuses (never clamped silently)."""


class IncompleteGroup(ConfigError):
    """Some of a group of parameters that are set together (or not at all) are set, the others (`missing`) not."""

    def __init__(self, group: tuple[str, ...], missing: list[str]):
        self.group, self.missing = group, missing
        finite = "all finite" if len(group) > 2 else "finite"
        super().__init__(f"{', '.join(group[:-1])} and {group[-1]} are set together ({finite}) or not at all")


@dataclass(frozen=True)
class Spec:
    """One parameter's declaration beside its default: Python type, range (bounds open or closed) or choices,
    whether unset (None) is allowed, whether it is fixed once the node runs, and its meaning."""

    doc: str
    kind: type
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    choices: tuple[str, ...] = ()
    optional: bool = False
    read_only: bool = False
    items: type = float  # a list's elements: finite numbers, or (str) names
    empty: bool = False  # a str that may be empty (unset: the feature is off)

    def check(self, name: str, value: Any):
        """Raise ConfigError naming the parameter when `value` breaks this declaration."""
        if value is None and self.optional:
            return
        if not self._typed(value) or not self._in_range(value):
            raise ConfigError(f"{name} must be {self.describe()}, got {value!r}{_number_as_text_hint(value)}")

    def _typed(self, value) -> bool:
        if self.kind is bool:
            return isinstance(value, bool)
        if self.kind is int:
            return isinstance(value, Integral) and not isinstance(value, bool)
        if self.kind is float:
            return _finite_number(value)
        if self.kind is list:
            element = _name if self.items is str else _finite_number
            return isinstance(value, Sequence) and not isinstance(value, str) and all(map(element, value)) and (
                self.low is None or self.low <= len(value)) and (self.high is None or len(value) <= self.high)
        if not isinstance(value, str):
            return False
        if self.empty and value == "":
            return True
        return value in self.choices if self.choices else bool(value) and not any(c.isspace() for c in value)

    def _in_range(self, value) -> bool:
        if self.kind is list:  # bounds on its length, checked with the type
            return True
        if self.low is not None and (value <= self.low if self.low_open else value < self.low):
            return False
        return self.high is None or (value < self.high if self.high_open else value <= self.high)

    def describe(self) -> str:
        """What a valid value is, in words: 'one of a, b', 'an integer >= 2', 'a finite number in (0, 1)'."""
        if self.kind is str:
            if self.choices:
                return f"one of {', '.join(self.choices)}"
            return "a name without spaces, or empty" if self.empty else "a name without spaces"
        if self.kind is bool:
            return "true or false"
        if self.kind is list:
            what = "names (letters, digits, _; not starting with a digit)" if self.items is str else "finite numbers"
            if self.low is not None and self.high is not None:
                return f"a list of {self.low:g} to {self.high:g} {what}"
            return f"a list of {what}"
        what = "an integer" if self.kind is int else "a finite number"
        if self.low is not None and self.high is not None:
            span = f"{'(' if self.low_open else '['}{self.low:g}, {self.high:g}{')' if self.high_open else ']'}"
            what += f" in {span}"
        elif self.low is not None:
            what += f" {'>' if self.low_open else '>='} {self.low:g}"
        elif self.high is not None:
            what += f" {'<' if self.high_open else '<='} {self.high:g}"
        return what + (" or unset" if self.optional else "")


def _name(value) -> bool:
    """A ROS name token: it can name a topic namespace (a station's inputs)."""
    return isinstance(value, str) and value.isidentifier() and value.isascii()


def _finite_number(value) -> bool:
    return isinstance(value, Real) and not isinstance(value, bool) and math.isfinite(value)


def param(default, doc: str, kind: type | None = None, **constraints):
    """A dataclass field with its declaration (`Spec`) in the field's metadata; the type follows the default
    unless given (for defaults that are None)."""
    kind = kind or (str if isinstance(default, str) else type(default))
    spec = Spec(doc, kind, optional=default is None or constraints.pop("optional", False), **constraints)
    return field(default=default, metadata={"spec": spec})


def choice(default: str, choices: tuple[str, ...], doc: str, **constraints):
    return param(default, doc, choices=choices, **constraints)


def variant_choice(who: str):
    """A filter group's `variant`: the default mcmc (moves that keep the posterior) or the paper as printed."""
    return choice("mcmc", ("mcmc", "paper"), f"{who}: `mcmc` (default: the paper's operator as a move that keeps the "
                  "posterior of all kept points, docs/design.md) or `paper` (as printed)")


@dataclass(frozen=True)
class ParameterSpec:
    """A declared parameter by its flat name (`afsa.visual`), with its default."""

    name: str
    default: Any
    spec: Spec


def unknown_names(names, known) -> str:
    """'num_particle: unknown; did you mean num_particles?' for each name, the nearest known one suggested."""
    parts = []
    for name in names:
        near = difflib.get_close_matches(name, list(known), n=1, cutoff=0.6)
        parts.append(f"{name}: unknown parameter" + (f"; did you mean {near[0]}?" if near else ""))
    return "; ".join(parts)


def _number_as_text_hint(value: Any) -> str:
    """A hint when a number came as text: YAML (ROS parameters, params files) reads `433e6` as a string, since its
    floats need a dot and a signed exponent."""
    items = value if isinstance(value, Sequence) and not isinstance(value, str) else [value]
    for text in (v for v in items if isinstance(v, str)):
        try:
            number = float(text)
        except ValueError:
            continue
        if not math.isfinite(number):
            continue
        mantissa, exponent = f"{number:e}".split("e")
        mantissa = mantissa.rstrip("0") + ("0" if mantissa.rstrip("0").endswith(".") else "")
        plain = f" or {number:.0f}" if number.is_integer() else ""
        return f" ({text!r} was read as text; YAML reads {mantissa}e{exponent}{plain} as a number)"
    return ""
