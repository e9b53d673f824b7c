"""aoa_localizer: find a radio emitter from a moving direction-finding vehicle.

The public names load when first used (PEP 562), so `import aoa_localizer` is light and a program's entry point
can take Ctrl-C from its first instant (aoa_localizer.common.start_up)."""
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from aoa_localizer.core.spec import ConfigError
    from aoa_localizer.engine.config import LocalizerConfig
    from aoa_localizer.engine.localizer import Localizer
    from aoa_localizer.engine.types import BearingInput, BearingPoseInput, Estimate, FixInput, Input
    from aoa_localizer.filters.afsa import AfsaConfig

_HOME = {"ConfigError": "aoa_localizer.core.spec", "LocalizerConfig": "aoa_localizer.engine.config",
         "Localizer": "aoa_localizer.engine.localizer", "BearingInput": "aoa_localizer.engine.types",
         "BearingPoseInput": "aoa_localizer.engine.types",
         "Estimate": "aoa_localizer.engine.types", "FixInput": "aoa_localizer.engine.types",
         "Input": "aoa_localizer.engine.types", "AfsaConfig": "aoa_localizer.filters.afsa"}
__all__ = ["AfsaConfig", "BearingInput", "BearingPoseInput", "ConfigError", "Estimate", "FixInput", "Input",
           "Localizer", "LocalizerConfig"]


def __getattr__(name: str) -> Any:
    home = _HOME.get(name)
    if home is None:
        raise AttributeError(f"module 'aoa_localizer' has no attribute {name!r}")
    value = globals()[name] = getattr(importlib.import_module(home), name)
    return value

