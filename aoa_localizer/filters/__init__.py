"""The particle filters, by the `algorithm` name users choose them with."""
from aoa_localizer.filters.afsa import AfsaFilter
from aoa_localizer.filters.agapf import AgaPfFilter
from aoa_localizer.filters.base import ParticleFilter
from aoa_localizer.filters.espf import EspfFilter
from aoa_localizer.filters.gfapf import GfapfFilter
from aoa_localizer.filters.sir import SirFilter
from aoa_localizer.filters.upf import PfDeFilter, UpfDeFilter, UpfFilter

FILTERS = {f.name: f for f in (SirFilter, AfsaFilter, EspfFilter, GfapfFilter, UpfDeFilter, UpfFilter, PfDeFilter,
                               AgaPfFilter)}


def make_filter(cfg, rng, model=None) -> ParticleFilter:
    """The filter `cfg.algorithm` names, with its own Generator, on `model` (default: the emitter problem)."""
    return FILTERS[cfg.algorithm](cfg, rng, model)
