"""Env contract: the torch vector env, the observation history and the library adapters.

The rsl_rl and Gymnasium adapters import their libraries, so they are imported from their
modules (``unigait.env.rsl_rl_env``, ``unigait.env.gymnasium_env``), not from here.
"""

from unigait.env.biped_pose import BipedPoseStats
from unigait.env.episode_stats import EpisodeStats
from unigait.env.history import ObservationHistory
from unigait.env.torch_env import TorchStep, TorchVecEnv

__all__ = ["BipedPoseStats", "EpisodeStats", "ObservationHistory", "TorchStep", "TorchVecEnv"]
