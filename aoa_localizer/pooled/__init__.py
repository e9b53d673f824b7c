"""One receiver pooled over its emitters: a hierarchical bearing model for surveys and fixed stations.

Each station's bearings of one emitter share a steady error (its site bias); the stations of one receiver share a
common bias and one error scale and tail weight, learned jointly over every emitter the receiver heard. Each
emitter's position posterior is evaluated on a grid that follows its stations' spread and bearings' crossings,
so nothing assumes a scale (docs/design.md, "Honest on real bearings").
"""
from aoa_localizer.pooled.solver import PooledResult, SurveyReading, locate_pooled

__all__ = ["PooledResult", "SurveyReading", "locate_pooled"]
