"""The particle filters, by the `algorithm` name users choose them with."""
from .afsa import AfsaFilter
from .agapf import AgaPfFilter
from .base import ParticleFilter
from .espf import EspfFilter
from .gfapf import GfapfFilter
from .sir import SirFilter
from .upf import PfDeFilter, UpfDeFilter, UpfFilter

FILTERS = {f.name: f for f in (SirFilter, AfsaFilter, EspfFilter, GfapfFilter, UpfDeFilter, UpfFilter, PfDeFilter,
                               AgaPfFilter)}


def make_filter(cfg, rng, model=None) -> ParticleFilter:
    """The filter `cfg.algorithm` names, with its own Generator, on `model` (default: the emitter problem)."""
    return FILTERS[cfg.algorithm](cfg, rng, model)
