"""Short path to the torch vector env (``unigait.env.torch_env``)."""

from unigait.env.torch_env import TorchStep, TorchVecEnv

__all__ = ["TorchStep", "TorchVecEnv"]
