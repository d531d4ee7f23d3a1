"""Perception: tracking-system plugins (ArUco markers on the head camera, static poses from the study file),
object query points, and the /perception/query service."""

from .aruco import ArucoTracker, detect_markers
from .base import Perception, Tracker
from .static import StaticTracker

__all__ = ["ArucoTracker", "Perception", "StaticTracker", "Tracker", "detect_markers"]
