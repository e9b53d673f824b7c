"""The particle filters, by the `algorithm` name users choose them with."""
from .afsa import AfsaFilter
from .base import ParticleFilter
from .espf import EspfFilter
from .gfapf import GfapfFilter
from .sir import SirFilter

FILTERS = {f.name: f for f in (SirFilter, AfsaFilter, EspfFilter, GfapfFilter)}


def make_filter(cfg, rng, model=None) -> ParticleFilter:
    """The filter `cfg.algorithm` names, with its own Generator, on `model` (default: the emitter problem)."""
    return FILTERS[cfg.algorithm](cfg, rng, model)
