"""Readings and observation points, below both the intake and the inference: a point's robust preprocessing
(gates, summaries) and the course-relative bearings' grouping."""
