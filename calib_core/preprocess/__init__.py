"""Preprocessing steps: outliers, zero-phase low-pass, clock alignment, segmentation.

Each step is a plain function ``(input, settings) -> (output, StepRecord)``;
import from the modules: ``outliers``, ``filters``, ``sync``, ``segments``.
``chain.preprocess`` runs them in a run's order from its ``run.settings`` tables.
"""
