"""aoa_localizer: find a radio emitter from a moving direction-finding vehicle."""
from aoa_localizer.core.spec import ConfigError
from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.localizer import Localizer
from aoa_localizer.engine.types import BearingInput, Estimate, FixInput, Input
from aoa_localizer.filters.afsa import AfsaConfig

__all__ = ["AfsaConfig", "BearingInput", "ConfigError", "Estimate", "FixInput", "Input", "Localizer", "LocalizerConfig"]
