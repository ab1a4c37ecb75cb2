"""The robot's left-right mirror on the actor's inputs and outputs, and the mirror loss.

The Go2 and the task are symmetric about the base's x-z plane: a mirrored state is as likely as
the state, and the mirrored action is what a symmetric policy does there. PPO does not see that
symmetry, and a CPU-length run drifts into lopsided gaits: one trot diagonal swinging 4.5 cm
and the other 8 cm, a biped turning at +0.1-0.3 rad/s on a straight command. The mirror loss
``mean (mu(M x) - M mu(x))^2``, with the target detached, pulls the actor towards the
symmetric policy (rsl_rl's mirror loss; decision record 0033).

Each map is a signed permutation, built from the session spec by field name, so a new field is
refused until someone says how it mirrors.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from unigait.client import Spec

#: Leg swap of the mirror: FL <-> FR, RL <-> RR (the order of joints, clocks, contacts, feet).
FOOT_SWAP = (1, 0, 3, 2)

#: Sign of each component of a three-vector field under the mirror (y -> -y). Velocities and
#: normals are vectors: y flips. Angular velocity is a pseudovector: x and z flip. The command
#: is (vx, vy, wz); the orientation (gravity y, pitch, gravity z).
VECTOR_SIGNS = {
    "cmd": (1.0, -1.0, -1.0),
    "phi": (-1.0, 1.0, 1.0),
    "omega": (-1.0, 1.0, -1.0),
    "base_lin_vel": (1.0, -1.0, 1.0),
    "terrain_normal": (1.0, -1.0, 1.0),
}
#: Per-joint fields (12, legs in FL FR RL RR order): legs swap, hip abductions flip sign.
JOINT_FIELDS = ("q", "qdot", "last_action")
#: Per-foot fields (4, FL FR RL RR): feet swap.
FOOT_FIELDS = ("clock", "foot_contact", "foot_height")
#: Fields the mirror leaves as they are: the task's one-hot mode and the gait's ratios.
UNCHANGED_FIELDS = ("mode", "ratio")


class UnknownField(ValueError):
    """A spec field this module does not know how to mirror."""


@dataclass(frozen=True)
class SignedPermutation:
    """``y[..., i] = sign[i] * x[..., index[i]]``: a mirror of a flat vector."""

    index: torch.Tensor
    sign: torch.Tensor

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        """The mirror of ``x``'s last axis."""
        return x[..., self.index] * self.sign

    def to(self, device: torch.device) -> SignedPermutation:
        """The same map on ``device``."""
        return SignedPermutation(self.index.to(device), self.sign.to(device))

    @staticmethod
    def concat(parts: list[SignedPermutation]) -> SignedPermutation:
        """The mirror of the concatenation of vectors that ``parts`` mirror, in order."""
        index, sign, offset = [], [], 0
        for p in parts:
            index.append(p.index + offset)
            sign.append(p.sign)
            offset += int(p.index.numel())
        return SignedPermutation(torch.cat(index), torch.cat(sign))


def joint_mirror(joint_names: tuple[str, ...]) -> SignedPermutation:
    """The 12 joints' mirror from their names: FL_* <-> FR_*, RL_* <-> RR_*, hips negated.

    Defaults are mirror-symmetric (hip abductions +-0.1, thighs and calves equal), so the same
    map holds for angles minus defaults, speeds and actions.
    """
    swap = {"FL": "FR", "FR": "FL", "RL": "RR", "RR": "RL"}
    position = {n: i for i, n in enumerate(joint_names)}
    index, sign = [], []
    for name in joint_names:
        leg, rest = name.split("_", 1)
        index.append(position[f"{swap[leg]}_{rest}"])
        sign.append(-1.0 if "hip" in rest else 1.0)
    return SignedPermutation(torch.tensor(index), torch.tensor(sign))


def field_mirror(name: str, size: int, joints: SignedPermutation) -> SignedPermutation:
    """The mirror of one named field of o_t or e_t."""
    if name in VECTOR_SIGNS and size == 3:
        return SignedPermutation(torch.arange(3), torch.tensor(VECTOR_SIGNS[name]))
    if name in JOINT_FIELDS and size == joints.index.numel():
        return joints
    if name in FOOT_FIELDS and size == len(FOOT_SWAP):
        return SignedPermutation(torch.tensor(FOOT_SWAP), torch.ones(len(FOOT_SWAP)))
    if name in UNCHANGED_FIELDS:
        return SignedPermutation(torch.arange(size), torch.ones(size))
    raise UnknownField(f"no mirror for field {name!r} of size {size}")


def tensor_mirror(spec: Spec, tensor: str) -> SignedPermutation:
    """The mirror of one spec tensor's row (``obs`` or ``labels``), field by field."""
    joints = joint_mirror(spec.joint_names)
    t = spec.tensor(tensor)
    covered = sum(f.size for f in t.fields)
    if covered != t.size:
        raise UnknownField(f"{tensor}'s fields cover {covered} of its {t.size} values")
    return SignedPermutation.concat([field_mirror(f.name, f.size, joints) for f in t.fields])


@dataclass(frozen=True)
class ActorMirror:
    """The mirror of the actor's input (o_t history, then the estimate) and of its actions."""

    actor_obs: SignedPermutation
    actions: SignedPermutation

    @staticmethod
    def from_spec(spec: Spec, history_length: int) -> ActorMirror:
        """From a session's spec and the history length (o_t's in the actor's input)."""
        obs = tensor_mirror(spec, "obs")
        labels = tensor_mirror(spec, "labels")
        actor_obs = SignedPermutation.concat([obs] * history_length + [labels])
        return ActorMirror(actor_obs, joint_mirror(spec.joint_names))

    def to(self, device: torch.device) -> ActorMirror:
        """The same maps on ``device``."""
        return ActorMirror(self.actor_obs.to(device), self.actions.to(device))


def mirror_loss(
    mean: torch.Tensor, mirrored_mean: torch.Tensor, mirror: ActorMirror
) -> torch.Tensor:
    """``mean((mu(M x) - M mu(x))^2)`` over batch and actions, the target ``M mu(x)`` detached.

    Args:
        mean: f32 [B, A] the actor's mean on the batch, mu(x).
        mirrored_mean: f32 [B, A] its mean on the mirrored batch, mu(M x).
        mirror: The maps.
    """
    return (mirrored_mean - mirror.actions(mean.detach())).square().mean()
