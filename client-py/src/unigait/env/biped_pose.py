"""What the robot does in biped mode, per iteration: how far up it is and what it rests on.

The biped reward can be collected in part without standing up: a robot pitched ~0.3 rad
nose-down with its head and front feet on the ground and its rear feet tucked up earns the full
"upright contacts" term (its head neither terminates nor is penalised). These shares tell that
stepping stone apart from the upright stance, which the reward curves alone do not.
"""

from __future__ import annotations

import torch

from unigait.client.spec import Spec
from unigait.env.torch_env import TorchStep

#: Biped mode in the step's ``mode`` tensor.
BIPED_MODE = 1


class BipedPoseStats:
    """Sums over the env-steps taken in biped mode, reported and cleared once per rollout.

    Pitch is the observed one (o_t, with the training's observation noise of +-0.05 rad), so
    the upright share is the task's I_up up to that noise near the threshold. Envs whose episode
    ended in the step are left out: their state is already the next episode's first one.

    Args:
        spec: The session spec (where pitch and foot contacts sit in ``obs`` and ``labels``).
        upright_pitch: Pitch above which the robot counts as upright (the task's I_up, rad).
        device: Where the sums live.
    """

    def __init__(self, spec: Spec, upright_pitch: float, device: torch.device) -> None:
        self.pitch_index = spec.pitch_index
        contact = spec.labels.field("foot_contact")
        # Feet in FL, FR, RL, RR order: the last two are the rear feet.
        self.rear_feet = slice(contact.offset + 2, contact.offset + 4)
        self.upright_pitch = upright_pitch
        self.device = device
        self.clear()

    def clear(self) -> None:
        """Start a new rollout's sums."""
        zero = torch.zeros((), device=self.device)
        self.steps = zero.clone()
        self.pitch = zero.clone()
        self.upright = zero.clone()
        self.rear_up = zero.clone()
        self.head_steps = zero.clone()  # biped env-steps with a head report (older servers: 0)
        self.head = zero.clone()

    def add(self, mode: torch.Tensor, after: TorchStep) -> None:
        """Add the envs that acted in biped mode (``mode``) and the state that left them in."""
        biped = (mode == BIPED_MODE) & ~after.dones
        pitch = torch.where(biped, after.obs[:, self.pitch_index], 0.0)
        self.steps += biped.sum()
        self.pitch += pitch.sum()
        self.upright += (biped & (pitch > self.upright_pitch)).sum()
        rear_up = (after.labels[:, self.rear_feet] < 0.5).all(dim=1)
        self.rear_up += (biped & rear_up).sum()
        if after.head_contact is not None:
            self.head_steps += biped.sum()
            self.head += (biped & after.head_contact).sum()

    def summary(self) -> dict[str, float]:
        """Means over this rollout's biped env-steps (NaN where there were none); then clear."""

        def share(total: torch.Tensor, count: torch.Tensor) -> float:
            return float(total) / float(count) if float(count) > 0 else float("nan")

        out = {
            "biped_pose/pitch": share(self.pitch, self.steps),
            "biped_pose/upright_share": share(self.upright, self.steps),
            "biped_pose/head_contact_share": share(self.head, self.head_steps),
            "biped_pose/rear_feet_up_share": share(self.rear_up, self.steps),
        }
        self.clear()
        return out
