"""The bootstrap SIR filter: the skeleton as it is (prior proposal, resampling when ESS falls)."""
from aoa_localizer.filters.base import ParticleFilter


class SirFilter(ParticleFilter):
    """Sampling-importance-resampling with the state model as proposal; the baseline every filter must beat."""

    name = "sir"
