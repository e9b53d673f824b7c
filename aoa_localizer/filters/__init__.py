"""The particle filters, by the `algorithm` name users choose them with, each in two variants: `mcmc` (the
default: the paper's operator as moves that keep the posterior of all kept points, for the emitter) and `paper`
(as printed, for the papers' own models)."""
import numpy as np

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.filters.afsa import AfsaFilter, AfsaMoves
from aoa_localizer.filters.agapf import AgaPfFilter, AgaPfMoves
from aoa_localizer.filters.base import FilterSettings, ParticleFilter
from aoa_localizer.filters.espf import EspfFilter, EspfMoves
from aoa_localizer.filters.gfapf import GfapfFilter, GfapfMoves
from aoa_localizer.filters.sir import SirFilter, SirMoves
from aoa_localizer.filters.upf import PfDeFilter, PfDeMoves, UpfDeFilter, UpfDeMoves, UpfFilter, UpfMoves
from aoa_localizer.models.base import CAPABILITY_WORDS, StateSpaceModel

# algorithm -> (the config group holding its `variant`, {variant: class})
FILTERS: dict[str, tuple[str, dict[str, type[ParticleFilter]]]] = {
    "sir": ("sir", {"paper": SirFilter, "mcmc": SirMoves}),
    "afsa": ("afsa", {"paper": AfsaFilter, "mcmc": AfsaMoves}),
    "espf": ("espf", {"paper": EspfFilter, "mcmc": EspfMoves}),
    "gfapf": ("gfapf", {"paper": GfapfFilter, "mcmc": GfapfMoves}),
    "upfde": ("de", {"paper": UpfDeFilter, "mcmc": UpfDeMoves}),
    "upf": ("upf", {"paper": UpfFilter, "mcmc": UpfMoves}),
    "pfde": ("de", {"paper": PfDeFilter, "mcmc": PfDeMoves}),
    "agapf": ("agapf", {"paper": AgaPfFilter, "mcmc": AgaPfMoves}),
}


class ModelMismatch(TypeError):
    """The model lacks a capability the chosen filter needs: the message names both."""


def filter_class(cfg: LocalizerConfig) -> type[ParticleFilter]:
    """The class `cfg.algorithm` and its group's `variant` name."""
    group, variants = FILTERS[cfg.algorithm]
    return variants[getattr(cfg, group).variant]


def make_filter(cfg: LocalizerConfig, rng: np.random.Generator, model: StateSpaceModel) -> ParticleFilter:
    """The filter `cfg.algorithm` names (in its group's variant), with its own Generator, on `model`, given only the
    settings filters read. Raises ModelMismatch when the model lacks a capability the filter needs."""
    cls = filter_class(cfg)
    missing = [CAPABILITY_WORDS[need] for need in cls.needs if not isinstance(model, need)]
    if missing:
        group = FILTERS[cfg.algorithm][0]
        mcmc = cls is FILTERS[cfg.algorithm][1]["mcmc"]
        hint = f" (the paper variant, {group}.variant: paper, may run on it)" if mcmc else ""
        raise ModelMismatch(f"{cfg.algorithm} ({group}.variant {getattr(cfg, group).variant}) needs a model with "
                            f"{' and '.join(missing)}; {type(model).__name__} has not{hint}")
    return cls(FilterSettings.of(cfg), rng, model)
