"""Fluency and team metrics (Hoffman 2019) from state updates: batch, live, readers, Gantt chart, CLI."""

from .fluency import compute_metrics
from .live import LiveMetrics
from .model import Counts, FluencyResult, Intervention, MetricsInputError, StateUpdate, TrialData, UnfinishedAction
from .readers import read_interventions, read_trial

__all__ = [
    "Counts",
    "FluencyResult",
    "Intervention",
    "LiveMetrics",
    "MetricsInputError",
    "StateUpdate",
    "TrialData",
    "UnfinishedAction",
    "compute_metrics",
    "read_interventions",
    "read_trial",
]
