"""Test doubles: a proto Spec, a numpy fake session and an in-process fake gRPC server."""

from __future__ import annotations

import json
import uuid
from concurrent import futures

import grpc
import numpy as np

from unigait.client import Spec, StepResult
from unigait.client.proto import pb, pb_grpc
from unigait.client.tensors import encode

OBS_FIELDS = [
    ("cmd", 3), ("phi", 3), ("omega", 3), ("q", 12), ("qdot", 12), ("last_action", 12),
    ("mode", 2), ("clock", 4), ("ratio", 2),
]  # fmt: skip
LABEL_FIELDS = [("base_lin_vel", 3), ("foot_contact", 4), ("terrain_normal", 3), ("foot_height", 4)]
PRIV_FIELDS = [
    ("friction", 1), ("payload", 1), ("com_offset", 3), ("joint_damping", 1),
    ("joint_friction", 1), ("armature", 1), ("kp_factor", 1), ("kd_factor", 1),
]  # fmt: skip
REWARD_TERMS = [
    "termination", "collision", "ang_vel_xy", "dof_vel", "dof_acc", "action_rate",
    "action_smoothness", "torques", "hip_pos", "dof_pos_limits", "quad_tracking_lin_vel",
    "quad_tracking_ang_vel", "quad_base_height", "quad_base_angle", "quad_lin_vel_z",
    "quad_periodic_gait", "quad_foot_clearance", "biped_tracking_lin_vel",
    "biped_tracking_ang_vel", "biped_base_height", "biped_base_angle", "biped_periodic_gait",
    "biped_foot_clearance", "biped_rear_legs", "biped_upright_contacts", "biped_body_contact",
    "biped_sideways_reach", "biped_feet_air_time",
]  # fmt: skip


#: Train-config overrides for small, fast learner runs against the fakes.
SMALL = [
    "runner.num_steps_per_env=6",
    "policy.actor_hidden_dims=[32, 16]",
    "policy.critic_hidden_dims=[32, 16]",
    "estimator.hidden_dims=[16]",
    "estimator.mini_batch_size=16",
    "runner.save_interval=2",
    "runner.plot_interval=1",
    "runner.quiet=true",
]


def _tensor_spec(name: str, fields: list[tuple[str, int]], dtype: int = pb.DTYPE_F32) -> object:
    msg = pb.TensorSpec(name=name, dtype=dtype)
    offset = 0
    for fname, size in fields:
        msg.fields.add(name=fname, offset=offset, size=size)
        offset += size
    if fields:
        msg.shape.append(offset)
    return msg


def proto_spec(num_envs: int, max_episode_steps: int = 5) -> object:
    """A ``unigait.v1.Spec`` shaped like the real server's."""
    msg = pb.Spec(
        protocol_version="1",
        server_version="fake",
        num_envs=num_envs,
        physics_dt=0.005,
        decimation=4,
        policy_dt=0.02,
        max_episode_steps=max_episode_steps,
        action_scale=0.25,
        joint_names=[
            f"{leg}_{j}" for leg in ("FL", "FR", "RL", "RR") for j in ("hip", "thigh", "calf")
        ],
        default_joint_pos=[0.1, 0.8, -1.5] * 4,
        reward_terms=REWARD_TERMS,
        autoreset=pb.AUTORESET_MODE_SAME_STEP,
        terrain="flat",
        task_config_toml="[rewards]\nupright_pitch = 1.4\n",
    )
    msg.tensors.append(_tensor_spec("obs", OBS_FIELDS))
    msg.tensors.append(_tensor_spec("labels", LABEL_FIELDS))
    msg.tensors.append(_tensor_spec("privileged", PRIV_FIELDS))
    msg.tensors.append(_tensor_spec("reward", []))
    msg.tensors.append(_tensor_spec("reward_terms", [(n, 1) for n in REWARD_TERMS]))
    return msg


class FakeSim:
    """N deterministic fake envs with same-step autoreset.

    obs[:, 0] is the env's age (steps into its episode), obs[:, 1] the env index; an episode times
    out at ``max_episode_steps``; env i terminates at age 2 when i % 4 == 3. Reward is
    0.1 - 0.01 * mean(action^2), split evenly over the terms.
    """

    def __init__(self, num_envs: int, seed: int = 0, max_episode_steps: int = 5) -> None:
        self.n = num_envs
        self.seed = seed
        self.max_steps = max_episode_steps
        self.age = np.arange(num_envs) % max_episode_steps
        self.rng = np.random.default_rng(seed)
        self.step_count = 0

    def obs(self) -> np.ndarray:
        o = np.zeros((self.n, 53), dtype=np.float32)
        o[:, 0] = self.age
        o[:, 1] = np.arange(self.n)
        o[:, 2] = self.seed
        o[:, 45:47] = [0.0, 1.0]
        return o

    def labels(self) -> np.ndarray:
        return np.tile(np.arange(14, dtype=np.float32) / 14, (self.n, 1)) + self.age[:, None]

    def privileged(self) -> np.ndarray:
        return np.full((self.n, 10), 0.5, dtype=np.float32)

    def result(self) -> dict[str, np.ndarray]:
        return {"obs": self.obs(), "labels": self.labels(), "privileged": self.privileged()}

    def initial(self) -> dict[str, np.ndarray]:
        """The first observations (ages staggered: env i starts at i % max_episode_steps)."""
        return {**self.result(), "reward": np.zeros(self.n, np.float32)}

    def reset(self, mask: np.ndarray | None = None) -> dict[str, np.ndarray]:
        m = np.ones(self.n, bool) if mask is None else mask.astype(bool)
        self.age[m] = 0
        out = self.result()
        out["reward"] = np.zeros(self.n, np.float32)
        return out

    def step(self, actions: np.ndarray) -> dict[str, np.ndarray]:
        if actions.shape != (self.n, 12):
            raise ValueError(f"actions must be f32 [{self.n}, 12], got {list(actions.shape)}")
        self.step_count += 1
        self.age += 1
        reward = (0.1 - 0.01 * np.mean(actions**2, axis=1)).astype(np.float32)
        k = len(REWARD_TERMS)
        terms = np.repeat(reward[:, None] / k, k, axis=1).astype(np.float32)
        terminated = (self.age == 2) & (np.arange(self.n) % 4 == 3)
        truncated = (self.age >= self.max_steps) & ~terminated
        ended = np.flatnonzero(terminated | truncated)
        final = {
            "final_obs": self.obs()[ended],
            "final_labels": self.labels()[ended],
            "final_privileged": self.privileged()[ended],
            "final_episode_length": self.age[ended].astype(np.uint32),
        }
        self.age[ended] = 0
        return {
            **self.result(),
            **final,
            "reward": reward,
            "reward_terms": terms,
            "terminated": terminated.astype(np.uint8),
            "truncated": truncated.astype(np.uint8),
            "final_env_ids": ended.astype(np.uint32),
            "mode": np.full(self.n, 2, np.uint8),
            "terrain_level": np.zeros(self.n, np.uint32),
        }


_DTYPES = {"terminated": "u1", "truncated": "u1", "mode": "u1", "final_env_ids": "<u4",
           "final_episode_length": "<u4", "terrain_level": "<u4"}  # fmt: skip


FAKE_UPRIGHT_PITCH = 1.25  # the upright threshold every fake step reports (rad)


def to_proto(fields: dict[str, np.ndarray], step_count: int = 0) -> object:
    """A ``unigait.v1.StepResult`` from arrays."""
    msg = pb.StepResult(step_count=step_count, upright_pitch=FAKE_UPRIGHT_PITCH)
    for name, value in fields.items():
        getattr(msg, name).CopyFrom(encode(value, _DTYPES.get(name, "<f4")))
    return msg


class FakeSession:
    """A :class:`unigait.client.SessionLike` over :class:`FakeSim`, without gRPC."""

    def __init__(self, num_envs: int, seed: int = 0, max_episode_steps: int = 5) -> None:
        self.sim = FakeSim(num_envs, seed, max_episode_steps)
        self.spec = Spec.from_proto(proto_spec(num_envs, max_episode_steps))
        self.initial = StepResult.from_proto(to_proto(self.sim.initial()), self.spec)
        self.closed = False

    def step(self, actions: np.ndarray, *, reward_terms: bool = False) -> StepResult:
        msg = to_proto(self.sim.step(np.asarray(actions, np.float32)), self.sim.step_count)
        return StepResult.from_proto(msg, self.spec)

    def reset(self, mask: np.ndarray | None = None) -> StepResult:
        return StepResult.from_proto(to_proto(self.sim.reset(mask)), self.spec)

    def close(self) -> None:
        self.closed = True


class FakeSimulator(pb_grpc.SimulatorServicer):
    """In-process gRPC server over :class:`FakeSim`, with the real server's status codes."""

    def __init__(self) -> None:
        self.sims: dict[str, FakeSim] = {}
        #: (scenario, seed) of each Evaluate request, in order.
        self.evaluated: list[tuple[str, int, int]] = []  # scenario, seed, envs
        self.evaluated_overrides: list[str] = []  # their task_overrides_toml
        #: ``policy_score`` reported for a policy, by its ONNX bytes (0 for any other).
        self.policy_scores: dict[bytes, float] = {}
        #: ``success_rate`` reported for a policy, by its ONNX bytes (none for any other), with
        #: ``trials`` equal to the request's envs.
        self.policy_success: dict[bytes, float] = {}
        #: The task overrides of each CreateSession request, in order.
        self.task_overrides: list[str] = []

    def _sim(self, session_id: str, context: grpc.ServicerContext) -> FakeSim:
        if session_id not in self.sims:
            context.abort(grpc.StatusCode.NOT_FOUND, f"no session {session_id!r}")
        return self.sims[session_id]

    def GetServerInfo(self, request: object, context: grpc.ServicerContext) -> object:
        return pb.ServerInfo(protocol_version="1", server_version="fake", max_envs_per_session=64,
                             max_sessions=8, active_sessions=len(self.sims), threads=1)  # fmt: skip

    def CreateSession(self, request: object, context: grpc.ServicerContext) -> object:
        cfg = request.config
        if not 0 < cfg.num_envs <= 64:
            context.abort(grpc.StatusCode.INVALID_ARGUMENT, "num_envs must be in 1..64")
        self.task_overrides.append(cfg.task_overrides_toml)
        sid = uuid.uuid4().hex
        self.sims[sid] = sim = FakeSim(cfg.num_envs, cfg.seed)
        return pb.CreateSessionResponse(
            session_id=sid, spec=proto_spec(cfg.num_envs), initial=to_proto(sim.initial())
        )

    def _step(self, request: object, sim: FakeSim, context: grpc.ServicerContext) -> object:
        a = np.frombuffer(request.actions.data, "<f4").reshape(tuple(request.actions.shape))
        try:
            return to_proto(sim.step(a), sim.step_count)
        except ValueError as err:
            context.abort(grpc.StatusCode.INVALID_ARGUMENT, str(err))

    def Step(self, request: object, context: grpc.ServicerContext) -> object:
        return self._step(request, self._sim(request.session_id, context), context)

    def StepStream(self, request_iterator: object, context: grpc.ServicerContext) -> object:
        sim = None
        for req in request_iterator:
            if sim is None:
                sim = self._sim(req.session_id, context)
            yield self._step(req, sim, context)

    def Reset(self, request: object, context: grpc.ServicerContext) -> object:
        sim = self._sim(request.session_id, context)
        mask = None
        if request.HasField("mask"):
            mask = np.frombuffer(request.mask.data, "u1")
        return to_proto(sim.reset(mask))

    def Evaluate(self, request: object, context: grpc.ServicerContext) -> object:
        if not request.policy_onnx:
            context.abort(grpc.StatusCode.INVALID_ARGUMENT, "policy_onnx is empty")
        self.evaluated.append((request.scenario, request.seed, request.num_envs))
        self.evaluated_overrides.append(request.task_overrides_toml)
        metrics = {
            "policy_bytes": float(len(request.policy_onnx)),
            "num_envs": request.num_envs,
            "seed": float(request.seed),
            "policy_score": self.policy_scores.get(request.policy_onnx, 0.0),
        }
        if request.policy_onnx in self.policy_success:
            metrics["success_rate"] = self.policy_success[request.policy_onnx]
            metrics["trials"] = float(request.num_envs)
        return pb.EvaluateResponse(
            metrics=metrics,
            report_json=json.dumps(
                {
                    "scenario": request.scenario,
                    "physics_engine": "articulated"
                    if "articulated" in request.task_overrides_toml
                    else "rapier",
                }
            ),
            recording_rrd=b"RRD" if request.record else b"",
        )

    def CloseSession(self, request: object, context: grpc.ServicerContext) -> object:
        self._sim(request.session_id, context)
        del self.sims[request.session_id]
        return pb.CloseSessionResponse()


def start_fake_server() -> tuple[grpc.Server, str, FakeSimulator]:
    """Start a :class:`FakeSimulator` on 127.0.0.1 with an OS-picked port."""
    # The Rust client pings every 30 s, idle or not (as the real server allows); gRPC core's
    # defaults would answer the second ping with GOAWAY "too many pings".
    options = [
        ("grpc.keepalive_permit_without_calls", 1),
        ("grpc.http2.min_ping_interval_without_data_ms", 1000),
        ("grpc.http2.max_ping_strikes", 0),
    ]
    server = grpc.server(futures.ThreadPoolExecutor(max_workers=4), options=options)
    servicer = FakeSimulator()
    pb_grpc.add_SimulatorServicer_to_server(servicer, server)
    port = server.add_insecure_port("127.0.0.1:0")
    server.start()
    return server, f"127.0.0.1:{port}", servicer
