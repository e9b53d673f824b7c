"""The particle filters, by the `algorithm` name users choose them with."""
import numpy as np

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.filters.afsa import AfsaFilter
from aoa_localizer.filters.agapf import AgaPfFilter
from aoa_localizer.filters.base import FilterSettings, ParticleFilter
from aoa_localizer.filters.espf import EspfFilter
from aoa_localizer.filters.gfapf import GfapfFilter
from aoa_localizer.filters.sir import SirFilter
from aoa_localizer.filters.upf import PfDeFilter, UpfDeFilter, UpfFilter
from aoa_localizer.models.base import CAPABILITY_WORDS, StateSpaceModel

FILTERS = {f.name: f for f in (SirFilter, AfsaFilter, EspfFilter, GfapfFilter, UpfDeFilter, UpfFilter, PfDeFilter,
                               AgaPfFilter)}


class ModelMismatch(TypeError):
    """The model lacks a capability the chosen filter needs: the message names both."""


def make_filter(cfg: LocalizerConfig, rng: np.random.Generator, model: StateSpaceModel) -> ParticleFilter:
    """The filter `cfg.algorithm` names, with its own Generator, on `model`, given only the settings filters read.
    Raises ModelMismatch when the model lacks a capability the filter needs."""
    cls = FILTERS[cfg.algorithm]
    missing = [CAPABILITY_WORDS[need] for need in cls.needs if not isinstance(model, need)]
    if missing:
        raise ModelMismatch(f"{cfg.algorithm} needs a model with {' and '.join(missing)}; "
                            f"{type(model).__name__} has not")
    return cls(FilterSettings.of(cfg), rng, model)
