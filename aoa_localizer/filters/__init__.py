"""The particle filters, by the `algorithm` name users choose them with, each in two variants: `mcmc` (the
default: ResampleMove sweeping with the paper's operator as moves that keep the posterior of all kept points, for
the emitter) and `paper` (as printed, for the papers' own models). registry.py names the filter modules, each
of which defines its `ALGORITHMS`."""
from typing import Any, cast

import numpy as np

from aoa_localizer.filters.base import FilterSettings, ParticleFilter
from aoa_localizer.filters.registry import REGISTRY
from aoa_localizer.filters.resample_move import MoveKernel, ResampleMove
from aoa_localizer.models.base import CAPABILITY_WORDS, StateSpaceModel


class ModelMismatch(TypeError):
    """The model lacks a capability the chosen filter needs: the message names both."""


def make_filter(cfg: Any, rng: np.random.Generator, model: StateSpaceModel, deferred: bool = False) -> ParticleFilter:
    """The filter `cfg.algorithm` names (in its group's variant), with its own Generator, on `model`, given only the
    settings filters read; `deferred`: a resample-move filter's sweeps are owed to its driver (ResampleMove).
    Raises ModelMismatch when the model lacks a capability the filter needs."""
    algorithm = REGISTRY[cfg.algorithm]
    paper, mcmc = cast(type[ParticleFilter], algorithm.paper), cast(type[MoveKernel], algorithm.mcmc)
    variant = getattr(cfg, algorithm.group).variant
    needs = (*ResampleMove.needs, *mcmc.needs) if variant == "mcmc" else paper.needs
    missing = [CAPABILITY_WORDS[need] for need in needs if not isinstance(model, need)]
    if missing:
        hint = f" (the paper variant, {algorithm.group}.variant: paper, may run on it)" if variant == "mcmc" else ""
        raise ModelMismatch(f"{cfg.algorithm} ({algorithm.group}.variant {variant}) needs a model with "
                            f"{' and '.join(missing)}; {type(model).__name__} has not{hint}")
    settings = FilterSettings.of(cfg)
    if variant == "mcmc":
        return ResampleMove(settings, rng, model, mcmc(), deferred)
    return paper(settings, rng, model)
