"""aoa_localizer: find a radio emitter from a moving direction-finding vehicle."""
from .config import AfsaConfig, ConfigError, LocalizerConfig
from .localizer import Localizer
from .types import Estimate

__all__ = ["AfsaConfig", "ConfigError", "Estimate", "Localizer", "LocalizerConfig"]
