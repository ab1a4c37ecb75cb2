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

    Args:
        spec: The session spec (where pitch and foot contacts sit in ``obs`` and ``labels``).
        upright_pitch: Pitch above which the robot counts as upright (the task's I_up, rad).
        device: Where the sums live.
    """

    def __init__(self, spec: Spec, upright_pitch: float, device: torch.device) -> None:
        # o_t's "phi" field is (gravity y, Euler pitch, gravity z); pitch is its second entry.
        self.pitch_index = spec.obs.field("phi").offset + 1
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
        self.head = zero.clone()
        self.rear_up = zero.clone()

    def add(self, mode: torch.Tensor, after: TorchStep) -> None:
        """Add the envs that acted in biped mode (``mode``) and the state they reached."""
        biped = mode == BIPED_MODE
        pitch = after.obs[:, self.pitch_index]
        self.steps += biped.sum()
        self.pitch += (pitch * biped).sum()
        self.upright += (biped & (pitch > self.upright_pitch)).sum()
        rear_up = (after.labels[:, self.rear_feet] < 0.5).all(dim=1)
        self.rear_up += (biped & rear_up).sum()
        if after.head_contact is not None:
            self.head += (biped & after.head_contact).sum()

    def summary(self) -> dict[str, float]:
        """Means over this rollout's biped env-steps (NaN when there were none); then clear."""
        n = float(self.steps)
        share = (lambda s: float(s) / n) if n > 0 else (lambda s: float("nan"))
        out = {
            "biped_pose/pitch": share(self.pitch),
            "biped_pose/upright_share": share(self.upright),
            "biped_pose/head_contact_share": share(self.head),
            "biped_pose/rear_feet_up_share": share(self.rear_up),
        }
        self.clear()
        return out
