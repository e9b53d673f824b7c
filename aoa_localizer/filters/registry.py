"""The algorithms by the name users choose them with. A filter module registers its algorithm where it defines it
(`register`); every list of algorithms, settings groups and variants elsewhere is read from here."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Algorithm:
    """One `algorithm` value: how the docs call it, its settings group (a frozen dataclass of `param()` fields whose
    `variant` picks the variant; two algorithms may share a group), its `paper` filter class and its `mcmc` move
    kernel (a MoveKernel class: the variant is a ResampleMove sweeping with it). Both are typed `type`: the filter
    modules import this one, so it names none of their classes."""

    name: str
    label: str
    group: str
    settings: type
    paper: type
    mcmc: type


REGISTRY: dict[str, Algorithm] = {}


def register(name: str, label: str, group: str, settings: type, paper: type, mcmc: type) -> None:
    """Make `name` an `algorithm` value; a group registered twice must hold the same settings class."""
    for other in REGISTRY.values():
        if other.group == group and other.settings is not settings:
            raise TypeError(f"settings group {group} is {other.settings.__name__}, not {settings.__name__}")
    REGISTRY[name] = Algorithm(name, label, group, settings, paper, mcmc)


def groups() -> dict[str, type]:
    """Each settings group by name, in the order the algorithms were registered."""
    return {a.group: a.settings for a in REGISTRY.values()}


def default_groups() -> tuple[tuple[str, Any], ...]:
    """Every group at its defaults: the `groups` of a configuration that sets none."""
    return tuple((name, cls()) for name, cls in groups().items())


class GroupAccess:
    """Reads a settings group as an attribute (`cfg.afsa`) from a dataclass's `groups` field of (name, settings)."""

    groups: tuple[tuple[str, Any], ...]

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__") or name == "groups":  # pickle and copy probe before `groups` exists
            raise AttributeError(name)
        for group, settings in self.groups:
            if group == name:
                return settings
        raise AttributeError(f"{type(self).__name__} has no {name}")
