"""Fluency and team metrics (Hoffman 2019) from state updates: batch, live, readers, Gantt chart, CLI."""

from .fluency import compute_metrics
from .live import LiveMetrics
from .model import Counts, FluencyResult, Intervention, StateUpdate, UnfinishedAction
from .readers import MetricsInputError, TrialData, read_interventions, read_trial

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
