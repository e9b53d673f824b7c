"""The algorithms by the name users choose them with: each filter module defines its `ALGORITHMS` and this list
names the modules, in the order the docs and the settings groups follow; every list of algorithms, settings groups
and variants elsewhere is read from here."""
from __future__ import annotations

from typing import Any

from aoa_localizer.filters import afsa, agapf, espf, gfapf, sir, upf
from aoa_localizer.filters.algorithm import Algorithm

FILTER_MODULES = (afsa, agapf, espf, gfapf, sir, upf)


def _registry(algorithms: tuple[Algorithm, ...]) -> dict[str, Algorithm]:
    """The algorithms by name; a name listed twice, or a group with two settings classes, is a programming error."""
    registry: dict[str, Algorithm] = {}
    for a in algorithms:
        if a.name in registry:
            raise TypeError(f"algorithm {a.name} is listed twice")
        for other in registry.values():
            if other.group == a.group and other.settings is not a.settings:
                raise TypeError(f"settings group {a.group} is {other.settings.__name__}, not {a.settings.__name__}")
        registry[a.name] = a
    return registry


REGISTRY: dict[str, Algorithm] = _registry(tuple(a for module in FILTER_MODULES for a in module.ALGORITHMS))


def groups() -> dict[str, type]:
    """Each settings group by name, in the order the algorithms are listed."""
    return {a.group: a.settings for a in REGISTRY.values()}


def default_groups() -> tuple[tuple[str, Any], ...]:
    """Every group at its defaults: the `groups` of a configuration that sets none."""
    return tuple((name, cls()) for name, cls in groups().items())
