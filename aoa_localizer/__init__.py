"""aoa_localizer: find a radio emitter from a moving direction-finding vehicle."""
from aoa_localizer.core.spec import ConfigError
from aoa_localizer.engine import survey_log
from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.localizer import Localizer
from aoa_localizer.engine.types import BearingInput, Estimate, FixInput, Input
from aoa_localizer.filters.afsa import AfsaConfig

__all__ = ["AfsaConfig", "BearingInput", "ConfigError", "Estimate", "FixInput", "Input", "Localizer", "LocalizerConfig"]


def _survey_model(records, receiver_class):
    """The engine's end-of-data survey model (aoa_localizer.pooled), imported when first needed."""
    from aoa_localizer.pooled.end_of_data import solve

    return solve(records, receiver_class)


survey_log.install_solver(_survey_model)
