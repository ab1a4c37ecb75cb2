"""Our Go2 (``assets/go2/go2.urdf``) as a MuJoCo model, set up like the server's rapier world.

Both simulators load the same URDF, so what differs between them is the engine, not the robot.
The URDF gives bodies, inertials, joints, limits and collision primitives; the rest is the
server's robot config and physics settings, written here once (the cross-check test compares
each value with what the cross-check driver, ``unigait-crosscheck``, reports):

- a free joint on ``base`` (the URDF root), or the base welded in place (``fixed_base_height``);
- URDF cylinders become capsules of the same radius and length (the server does the same, as
  legged_gym's ``replace_cylinder_with_capsule``);
- joint armature 0.02 kg m^2, viscous damping 0.3 N m s/rad and Coulomb friction 0.0075 N m
  (MuJoCo's ``armature``, ``damping``, ``frictionloss``);
- the server's floor of 0.002 kg m^2 on each diagonal entry of a leg link's inertia tensor
  (``physics.min_link_inertia``), applied to the URDF matrix before MuJoCo diagonalises it
  (0 gives the URDF's own inertia);
- robot geoms touch only the floor (no self-collision), friction 1.0, no restitution, an
  elliptic friction cone with impratio 100 (near-rigid friction, see :class:`PhysicsOptions`);
- torques come from outside (the PD law in :mod:`unigait.mujoco.sim`), so there are no
  MuJoCo actuators.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from unigait.assets import go2_urdf

JOINT_NAMES: tuple[str, ...] = tuple(
    f"{leg}_{part}_joint" for leg in ("FL", "FR", "RL", "RR") for part in ("hip", "thigh", "calf")
)
"""The 12 joints in action order (FL, FR, RL, RR x hip, thigh, calf)."""

FOOT_GEOMS: tuple[str, ...] = ("FL_foot", "FR_foot", "RL_foot", "RR_foot")
"""Foot collision spheres, leg order."""

HEAD_GEOMS: tuple[str, ...] = ("base_head_upper", "base_head_lower")
"""The head's collision elements (reported; neither the trunk nor penalised)."""

DEFAULT_Q = np.array(
    [0.1, 0.8, -1.5, -0.1, 0.8, -1.5, 0.1, 1.0, -1.5, -0.1, 1.0, -1.5], dtype=np.float64
)
"""Joint angles at action zero (rad), action order: the server's ``RobotConfig::default()``."""

LEG_LINK_SUFFIXES = ("_hip", "_thigh", "_calf")


def find_go2_urdf() -> Path:
    """Path of the Go2 URDF: ``$UNIGAIT_GO2_URDF`` or the package's copy of ``assets/go2``.

    Raises:
        FileNotFoundError: When the file is missing (a build that left out the package data).
    """
    env = os.environ.get("UNIGAIT_GO2_URDF")
    path = Path(env) if env else go2_urdf()
    if not path.is_file():
        hint = (
            "set by $UNIGAIT_GO2_URDF"
            if env
            else "the package's copy of assets/go2: reinstall client-py, whose build adds it"
        )
        raise FileNotFoundError(f"Go2 URDF {path} not found ({hint})")
    return path


@dataclass(frozen=True)
class PhysicsOptions:
    """How the MuJoCo model is set up. Defaults: the server's nominal values.

    Attributes:
        dt: Physics step (s). 0.005 (200 Hz).
        gravity: Gravity along -z (m/s^2). 9.81.
        kp: PD stiffness (N m/rad). 20.
        kd: PD damping (N m s/rad). 0.5.
        armature: Rotor inertia of each joint (kg m^2). 0.02.
        armature_on_links: Where the armature goes. False (default): MuJoCo's ``armature``, an
            inertia on the joint coordinate only (a geared rotor's reflected inertia: it adds to
            the mass matrix's diagonal and couples to nothing). True: as the server does it,
            added to the child link's inertia tensor about the joint axis (``armature * a a^T``
            at the COM), so the link carries it as rigid-body inertia: it also resists the
            trunk's rotation and couples parallel joints (a thigh turns its calf's armature
            too). A diagnostic to separate the armature model from the engines.
        joint_damping: Passive viscous joint damping (N m s/rad). 0.3.
        joint_friction: Coulomb joint friction (N m), MuJoCo ``frictionloss``. 0.0075.
        min_link_inertia: Floor on each diagonal inertia entry of the leg links (kg m^2), the
            server's ``physics.min_link_inertia``. 0.002; 0 keeps the URDF's inertia.
        friction: Robot-ground sliding friction (the server multiplies the robot's value by the
            ground's 1.0). 1.0.
        fixed_base_height: None: free-floating base. A height (m): the base is welded level
            at (0, 0, height) (the server's ``lock_trunk(LockedAxes::all())``).
        cone: Friction cone, ``"elliptic"`` or ``"pyramidal"``. Elliptic.
        solver: Constraint solver, ``"newton"`` (MuJoCo's default), ``"cg"`` or ``"pgs"``.
        solref: Contact ``solref`` (time constant s, damping ratio). MuJoCo's default
            (0.02, 1).
        iterations: Solver iterations. 100 (MuJoCo's default).
        ls_iterations: Line-search iterations of the Newton / CG solvers. 50 (MuJoCo's default).
        integrator: ``"implicitfast"`` (damping implicit) or ``"euler"``.
        impratio: Ratio of frictional to normal constraint impedance. 100, as the menagerie
            Go2: with MuJoCo's default 1 the soft friction lets loaded feet creep, and a robot
            standing at the default pose splays its feet 2.5-4.6 cm sideways and sits 13-15 mm
            lower than with (near-)rigid Coulomb friction, which rapier and the robot have.
        noslip_iterations: MuJoCo's no-slip post-solver iterations. 0 (impratio does the job;
            10 gives the same standing height within 0.1 mm).
        position_actuators: Add one MuJoCo position actuator per joint (action order) with
            the PD law ``clip(kp (ctrl - q) - kd qdot, +-effort)``, so that a batch can step in
            C with ``ctrl`` = joint targets (the benchmark). False: torques come from outside.
    """

    dt: float = 0.005
    gravity: float = 9.81
    kp: float = 20.0
    kd: float = 0.5
    armature: float = 0.02
    armature_on_links: bool = False
    joint_damping: float = 0.3
    joint_friction: float = 0.0075
    min_link_inertia: float = 0.002
    friction: float = 1.0
    fixed_base_height: float | None = None
    cone: str = "elliptic"
    solver: str = "newton"
    solref: tuple[float, float] = (0.02, 1.0)
    iterations: int = 100
    ls_iterations: int = 50
    integrator: str = "implicitfast"
    impratio: float = 100.0
    noslip_iterations: int = 0
    position_actuators: bool = False


@dataclass
class Go2Model:
    """A compiled MuJoCo Go2 and the indices the simulation needs.

    Attributes:
        model: The compiled ``mujoco.MjModel``.
        options: What it was built with.
        qpos_adr: int [12] qpos address of each joint, action order.
        dof_adr: int [12] qvel / qfrc address of each joint, action order.
        effort: float [12] motor torque limits from the URDF (N m).
        foot_geoms: int [4] geom ids of the foot spheres, leg order.
        trunk_geoms: Geom ids of the trunk (contact terminates an episode).
        head_geoms: Geom ids of the head.
        foot_radius: float [4] foot sphere radii (m).
        free: Whether the base has a free joint.
    """

    model: mujoco.MjModel
    options: PhysicsOptions
    qpos_adr: np.ndarray
    dof_adr: np.ndarray
    effort: np.ndarray
    foot_geoms: np.ndarray
    trunk_geoms: frozenset[int]
    head_geoms: frozenset[int]
    foot_radius: np.ndarray
    free: bool = True
    geom_role: dict[int, str] = field(default_factory=dict)


def _urdf_tables(path: Path) -> tuple[dict[str, float], dict[str, np.ndarray]]:
    """Effort limits per joint and inertia matrices (3 x 3, at the COM) per link."""
    root = ET.parse(path).getroot()
    effort = {}
    for j in root.iter("joint"):
        limit = j.find("limit")
        if limit is not None:
            effort[j.attrib["name"]] = float(limit.attrib["effort"])
    inertia = {}
    for link in root.iter("link"):
        node = link.find("inertial/inertia")
        if node is None:
            continue
        a = {k: float(v) for k, v in node.attrib.items()}
        inertia[link.attrib["name"]] = np.array(
            [
                [a["ixx"], a["ixy"], a["ixz"]],
                [a["ixy"], a["iyy"], a["iyz"]],
                [a["ixz"], a["iyz"], a["izz"]],
            ]
        )
    return effort, inertia


def _add_armature_to_links(
    model: mujoco.MjModel, link_inertia: dict[str, np.ndarray], armature: float
) -> None:
    """Add ``armature * a a^T`` to each leg link's inertia tensor, as the server does.

    The sum usually breaks the triangle inequality of a rigid body's principal moments (a light
    hip gets 0.02 about x on top of ~0.002 about y and z), which MuJoCo's compiler refuses; so
    the compiled model's principal inertia and its frame are overwritten and the derived
    constants recomputed (``mj_setConst``).
    """
    for name in JOINT_NAMES:
        j = model.joint(name).id
        body = int(model.jnt_bodyid[j])
        axis = np.asarray(model.jnt_axis[j], dtype=np.float64)
        axis /= np.linalg.norm(axis)
        full = link_inertia[model.body(body).name] + armature * np.outer(axis, axis)
        moments, frame = np.linalg.eigh(full)
        if np.linalg.det(frame) < 0:
            frame[:, 0] *= -1.0
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, frame.flatten())
        model.body_inertia[body] = moments
        model.body_iquat[body] = quat
    mujoco.mj_setConst(model, mujoco.MjData(model))


def _add_position_actuators(
    spec: mujoco.MjSpec, efforts: dict[str, float], kp: float, kd: float
) -> None:
    """One position actuator per joint in action order (see ``position_actuators``)."""
    for name in JOINT_NAMES:
        act = spec.add_actuator()
        act.name = f"{name}_pd"
        act.trntype = mujoco.mjtTrn.mjTRN_JOINT
        act.target = name
        act.gainprm[0] = kp
        act.biastype = mujoco.mjtBias.mjBIAS_AFFINE
        act.biasprm[0:3] = [0.0, -kp, -kd]
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.forcerange = [-efforts[name], efforts[name]]


def build_model(options: PhysicsOptions | None = None, urdf: Path | None = None) -> Go2Model:
    """Compile our Go2 URDF into MuJoCo with ``options`` (default: the server's nominal setup).

    Args:
        options: Model options; None = :class:`PhysicsOptions` defaults.
        urdf: The URDF; None = :func:`find_go2_urdf`.

    Returns:
        The compiled model with joint, foot and contact indices in the server's order.
    """
    options = options or PhysicsOptions()
    path = urdf or find_go2_urdf()
    efforts, inertias = _urdf_tables(path)
    spec = mujoco.MjSpec.from_file(str(path))
    spec.compiler.fusestatic = False  # keep `base` a body of its own (the URDF root)
    spec.compiler.discardvisual = True
    spec.option.timestep = options.dt
    spec.option.gravity = [0.0, 0.0, -options.gravity]
    spec.option.cone = {
        "elliptic": mujoco.mjtCone.mjCONE_ELLIPTIC,
        "pyramidal": mujoco.mjtCone.mjCONE_PYRAMIDAL,
    }[options.cone]
    spec.option.solver = {
        "newton": mujoco.mjtSolver.mjSOL_NEWTON,
        "cg": mujoco.mjtSolver.mjSOL_CG,
        "pgs": mujoco.mjtSolver.mjSOL_PGS,
    }[options.solver]
    spec.option.integrator = {
        "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
        "euler": mujoco.mjtIntegrator.mjINT_EULER,
    }[options.integrator]
    spec.option.iterations = options.iterations
    spec.option.ls_iterations = options.ls_iterations
    spec.option.impratio = options.impratio
    spec.option.noslip_iterations = options.noslip_iterations

    base = spec.body("base")
    if options.fixed_base_height is None:
        base.add_freejoint()
    else:
        base.pos = [0.0, 0.0, options.fixed_base_height]

    link_inertia: dict[str, np.ndarray] = {}
    for body in spec.bodies:
        name = body.name
        if name in inertias and name.endswith(LEG_LINK_SUFFIXES):
            full = inertias[name].copy()
            for i in range(3):
                full[i, i] = max(full[i, i], options.min_link_inertia)
            link_inertia[name] = full
            body.fullinertia = [
                full[0, 0],
                full[1, 1],
                full[2, 2],
                full[0, 1],
                full[0, 2],
                full[1, 2],
            ]
            body.explicitinertial = True

    for j in spec.joints:
        if j.name in efforts:
            j.armature = 0.0 if options.armature_on_links else options.armature
            j.damping = [options.joint_damping, 0.0, 0.0]
            j.frictionloss = options.joint_friction

    for g in spec.geoms:
        if g.type == mujoco.mjtGeom.mjGEOM_CYLINDER:
            g.type = mujoco.mjtGeom.mjGEOM_CAPSULE
        g.contype = 1
        g.conaffinity = 0
        g.condim = 3
        g.friction = [options.friction, 0.0, 0.0]
        g.solref = list(options.solref)
        g.margin = 0.0

    if options.position_actuators:
        _add_position_actuators(spec, efforts, options.kp, options.kd)

    floor = spec.worldbody.add_geom()
    floor.name = "floor"
    floor.type = mujoco.mjtGeom.mjGEOM_PLANE
    floor.size = [0.0, 0.0, 1.0]
    floor.contype = 0
    floor.conaffinity = 1
    floor.condim = 3
    floor.friction = [1.0, 0.0, 0.0]
    floor.solref = list(options.solref)

    model = spec.compile()
    if options.armature_on_links:
        _add_armature_to_links(model, link_inertia, options.armature)
    joints = [model.joint(n) for n in JOINT_NAMES]
    foot_geoms = np.array([model.geom(n).id for n in FOOT_GEOMS])
    base_id = model.body("base").id
    head = frozenset(model.geom(n).id for n in HEAD_GEOMS)
    trunk = frozenset(
        int(g) for g in range(model.ngeom) if model.geom_bodyid[g] == base_id and g not in head
    )
    roles: dict[int, str] = {}
    for g in range(model.ngeom):
        if g in trunk:
            roles[g] = "trunk"
        elif g in head:
            roles[g] = "head"
        elif g in set(foot_geoms.tolist()):
            roles[g] = "foot"
        elif model.geom(g).name != "floor":
            roles[g] = "leg"
    return Go2Model(
        model=model,
        options=options,
        qpos_adr=np.array([int(j.qposadr[0]) for j in joints]),
        dof_adr=np.array([int(j.dofadr[0]) for j in joints]),
        effort=np.array([efforts[n] for n in JOINT_NAMES]),
        foot_geoms=foot_geoms,
        trunk_geoms=trunk,
        head_geoms=head,
        foot_radius=np.array([float(model.geom_size[g][0]) for g in foot_geoms]),
        free=options.fixed_base_height is None,
        geom_role=roles,
    )
