"""aoa_localizer: find a radio emitter from a moving direction-finding vehicle."""
from aoa_localizer.engine.config import AfsaConfig, ConfigError, LocalizerConfig
from aoa_localizer.engine.localizer import Localizer
from aoa_localizer.engine.types import Estimate

__all__ = ["AfsaConfig", "ConfigError", "Estimate", "Localizer", "LocalizerConfig"]
