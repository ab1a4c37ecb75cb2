"""Rerun recordings of MuJoCo rollouts, in the layout of the server's recorder.

Entity paths as ``server/record/src/entity.rs``: ``world`` (Z up), ``world/robot/<body>``
with its colliders as ``geom<k>`` (static), ``world/terrain``, ``world/feet`` (coloured by
contact), ``world/command`` and ``world/velocity`` arrows, ``contact/<foot>``, ``command/*``,
``state/base_height``, ``state/pitch``, ``state/yaw_rate``, ``mode`` and ``events``; timelines
``step`` and ``sim_time``. Rewards are not computed in MuJoCo, so ``reward/*`` is absent.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from unigait.mujoco.sim import CONTACT_FORCE_N, euler_pitch
from unigait.mujoco.vec_env import MujocoVecEnv, heading_direction

FOOT_NAMES = ("FL", "FR", "RL", "RR")
BODY_COLOR = (70, 110, 170)
PENALISED_COLOR = (225, 140, 60)
FOOT_COLOR = (40, 40, 40)
OTHER_COLOR = (150, 150, 150)


def _xyzw(wxyz: np.ndarray) -> list[float]:
    w, x, y, z = (float(v) for v in wxyz)
    return [x, y, z, w]


class Sim2SimRecorder:
    """Records one env of a :class:`MujocoVecEnv` to an ``.rrd`` file.

    Args:
        path: Output file.
        env_index: The env followed.
        name: Recording name.
    """

    def __init__(self, path: str | Path, env_index: int = 0, name: str = "sim2sim") -> None:
        import rerun as rr

        self.rr = rr
        self.path = Path(path)
        self.env_index = env_index
        self.rec = rr.RecordingStream("unigait", recording_id=None)
        self.rec.save(str(self.path))
        self.rec.send_recording_name(name)
        self.last_mode: int | None = None

    def begin(self, env: MujocoVecEnv) -> None:
        """Log the static scene and the state at step 0."""
        rr, rec = self.rr, self.rec
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        go2 = env.sims[self.env_index].go2
        m = go2.model
        counts: dict[int, int] = {}
        for g in sorted(go2.geom_role):
            b = int(m.geom_bodyid[g])
            k = counts.get(b, 0)
            counts[b] = k + 1
            path = f"world/robot/{m.body(b).name}/geom{k}"
            rec.log(
                path,
                rr.Transform3D(
                    translation=m.geom_pos[g].tolist(), quaternion=_xyzw(m.geom_quat[g])
                ),
                static=True,
            )
            role = go2.geom_role[g]
            name = m.body(b).name
            if role in ("trunk", "head"):
                color = BODY_COLOR
            elif role == "foot":
                color = FOOT_COLOR
            elif "thigh" in name or "calf" in name:
                color = PENALISED_COLOR
            else:
                color = OTHER_COLOR
            size = m.geom_size[g]
            kind = m.geom_type[g]
            solid = rr.components.FillMode.Solid
            if kind == mujoco.mjtGeom.mjGEOM_BOX:
                shape = rr.Boxes3D(half_sizes=[size.tolist()], colors=[color], fill_mode=solid)
            elif kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
                length = 2.0 * float(size[1])
                shape = rr.Capsules3D(
                    lengths=[length],
                    radii=[float(size[0])],
                    translations=[[0.0, 0.0, -length / 2.0]],
                    colors=[color],
                    fill_mode=solid,
                )
            else:
                shape = rr.Ellipsoids3D(radii=[float(size[0])], colors=[color], fill_mode=solid)
            rec.log(path, shape, static=True)
        half = 6.0
        rec.log(
            "world/terrain",
            rr.Mesh3D(
                vertex_positions=[
                    [-half, -half, 0],
                    [half, -half, 0],
                    [half, half, 0],
                    [-half, half, 0],
                ],
                triangle_indices=[[0, 1, 2], [0, 2, 3]],
                vertex_colors=[[110, 110, 100]] * 4,
            ),
            static=True,
        )
        self.log_step(env, 0)

    def log_step(self, env: MujocoVecEnv, step: int) -> None:
        """Log the state after policy step ``step`` (0 = the initial state)."""
        rr, rec, i = self.rr, self.rec, self.env_index
        rec.set_time("step", sequence=step)
        rec.set_time("sim_time", duration=step * env.settings.policy_dt)
        sim = env.sims[i]
        m, d = sim.model, sim.data
        for b in range(1, m.nbody):
            rec.log(
                f"world/robot/{m.body(b).name}",
                rr.Transform3D(translation=d.xpos[b].tolist(), quaternion=_xyzw(d.xquat[b])),
            )
        s = env.states[i]
        contact = s.foot_force > CONTACT_FORCE_N
        rec.log(
            "world/feet",
            rr.Points3D(
                s.foot_pos,
                radii=(sim.go2.foot_radius * 1.2).tolist(),
                colors=[(40, 200, 80) if c else (200, 200, 200) for c in contact],
                labels=list(FOOT_NAMES),
            ),
        )
        for name, c in zip(FOOT_NAMES, contact, strict=True):
            rec.log(f"contact/{name}", rr.Scalars(float(c)))
        h = heading_direction(s.rotation)
        c = env.command[i]
        command_world = [c[0] * h[0] - c[1] * h[1], c[0] * h[1] + c[1] * h[0], 0.0]
        base = s.base_pos.tolist()
        rec.log(
            "world/command",
            rr.Arrows3D(vectors=[command_world], origins=[base], colors=[(60, 120, 255)]),
        )
        rec.log(
            "world/velocity",
            rr.Arrows3D(vectors=[s.base_linvel.tolist()], origins=[base], colors=[(255, 80, 80)]),
        )
        mode = int(env.mode[i])
        for path, value in (
            ("command/vx", c[0]),
            ("command/vy", c[1]),
            ("command/wz", c[2]),
            ("state/base_height", s.base_pos[2]),
            ("state/pitch", euler_pitch(s.base_quat)),
            ("state/yaw_rate", s.base_angvel[2]),
            ("mode", mode),
        ):
            rec.log(path, rr.Scalars(float(value)))
        if step > 0 and (env.terminated[i] or env.truncated[i]):
            what = "terminated (base contact)" if env.terminated[i] else "time-out"
            rec.log("events", rr.TextLog(f"episode ended: {what}; env reset"))
        if self.last_mode != mode:
            rec.log("events", rr.TextLog(f"mode: {'biped' if mode == 1 else 'quad'}"))
            self.last_mode = mode

    def finish(self) -> None:
        """Flush and close the file."""
        self.rec.flush()
        self.rec.disconnect()
