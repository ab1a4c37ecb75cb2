"""Logging and timing helpers."""

from unigait.utils.logger import Timers, TrainLogger

__all__ = ["Timers", "TrainLogger"]
