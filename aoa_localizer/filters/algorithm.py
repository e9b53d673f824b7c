"""What an algorithm is (`Algorithm`: its name, label, settings group and its two variants' classes) and how a
configuration reads its settings groups (`GroupAccess`); the registry lists the algorithms."""
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
