"""The particle filters, by the `algorithm` name users choose them with."""
from .afsa import AfsaFilter
from .base import ParticleFilter
from .sir import SirFilter

FILTERS = {f.name: f for f in (SirFilter, AfsaFilter)}


def make_filter(cfg, rng) -> ParticleFilter:
    """The filter `cfg.algorithm` names, with its own Generator."""
    return FILTERS[cfg.algorithm](cfg, rng)
