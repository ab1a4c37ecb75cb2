"""Physics cross-checks: our rapier Go2 against MuJoCo running the same URDF (issue 13).

Ours: ``target/release/unigait-crosscheck`` or ``$UNIGAIT_CROSSCHECK_BIN`` (build it with
``cargo build --release -p unigait-crosscheck``; these tests skip, saying so, only when it is
missing). MuJoCo:
``unigait.mujoco.scenarios`` in-process. Both run the same initial states and target sequences
(each scenario's ``params`` must agree) and every figure is compared with the tolerance written
in :data:`CHECKS`: ``abs`` bounds |ours - MuJoCo| in the figure's unit, ``rel`` bounds
|ours / MuJoCo - 1|. The issue's aims: standing height within 5 mm, step response times within
10%, trot speed within 20%.

Measured exceptions (working tree of 2026-11-23: armature added to each leg link's inertia about
its joint axis, all four hips included). The engines model the rotor differently: MuJoCo's
``armature`` is an inertia on the joint coordinate only, ours is rigid-body inertia of the child
link (``armature * a a^T`` at its COM), which also resists the trunk's rotation (whole body 43%
harder to roll and 32% harder to pitch at 0.02 kg m^2) and couples parallel joints (a thigh
turns its calf's armature too). So every figure is compared three ways:

- :func:`test_figure_agrees`: nominal physics, MuJoCo's own armature. The checks the armature
  model moves are expected failures (:data:`ARMATURE_MODEL_EXCEPTIONS`, measured figures in each
  reason); all of them pass once MuJoCo carries the armature on the links as we do;
- :func:`test_figure_agrees_with_link_armature`: nominal physics, MuJoCo with the armature on
  the links (``PhysicsOptions(armature_on_links=True)``): one engine difference left, the
  forward trot's speed (:data:`LINK_ARMATURE_EXCEPTIONS`);
- :func:`test_figure_agrees_at_low_armature`: both at armature 0.0005 (on the links), which
  isolates the model, contacts and actuation (:data:`LOW_ARMATURE_EXCEPTIONS`);
- :func:`test_figure_agrees_articulated`: our articulated engine (issue 34: armature on the
  joint, the URDF's inertias) against MuJoCo with the same model, the same contact time
  constant and the pyramidal cone (:data:`ARTICULATED_CONE`): no difference left.

The open-loop trots are contact-rich and unstabilised, and their figures follow the contact
model: MuJoCo's contacts are soft (``solref`` time constant 0.02 s) where rapier's are near rigid;
at the stiffest MuJoCo accepts at a 5 ms step (0.01 s) its forward trot speeds up from 0.36 to
0.47 m/s at armature 0.0005 (ours 0.61) and from 0.18 to 0.20 m/s with the nominal link armature
(ours 0.28). The friction settings barely matter (0.36-0.37 m/s with impratio 1, a pyramidal
cone or 10 no-slip iterations) and the targets are the same at the same physics steps
(:func:`test_both_engines_run_the_same_scenario`); our solver's convergence moves our own
figures too (8 substeps instead of 2: forward trot 0.25 instead of 0.28 m/s).

``python tests/test_mujoco_crosscheck.py [ARMATURE]`` prints the table (ours, MuJoCo with its own
armature and with link armature, ratios, tolerance, pass/xfail/FAIL) for docs/src/mujoco.md.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("mujoco", reason="the MuJoCo tests need the `mujoco` extra")

from unigait.mujoco import scenarios
from unigait.mujoco.crosscheck import run_ours
from unigait.mujoco.model import PhysicsOptions


@dataclass(frozen=True)
class Check:
    """One figure compared between the engines."""

    scenario: str
    quantity: str
    kind: str  # "abs" or "rel"
    tolerance: float
    why: str = ""

    def error(self, ours: float, mujoco: float) -> float:
        """|ours - MuJoCo| (abs) or |ours / MuJoCo - 1| (rel)."""
        if not (math.isfinite(ours) and math.isfinite(mujoco)):
            return math.inf
        if self.kind == "abs":
            return abs(ours - mujoco)
        return abs(ours / mujoco - 1.0) if mujoco != 0.0 else math.inf


CHECKS: list[Check] = [
    # The model: one URDF, so mass and kinematics agree to rounding.
    Check("robot", "mass_kg", "abs", 1e-3),
    Check("robot", "standing_base_z", "abs", 1e-5, "forward kinematics of the default pose"),
    Check("robot", "whole_body_inertia[0]", "rel", 1e-3, "inertia floor included on both"),
    Check("robot", "whole_body_inertia[1]", "rel", 1e-3),
    Check("robot", "whole_body_inertia[2]", "rel", 1e-3),
    # One joint's step response (0.3 rad), trunk held: the aim, times within 10%.
    *(
        c
        for j in ("hip", "thigh", "calf")
        for c in (
            Check(f"step_{j}", "rise_time_s", "rel", 0.10),
            Check(f"step_{j}", "peak_time_s", "rel", 0.10),
            Check(f"step_{j}", "overshoot", "abs", 0.03, "fraction of the step"),
            Check(f"step_{j}", "settled_error_rad", "abs", 0.003),
        )
    ),
    # Standing at the default pose: height within 5 mm (the aim), forces within 5% per foot.
    Check("stand", "base_height_m", "abs", 0.005),
    Check("stand", "pitch_rad", "abs", 0.01),
    Check("stand", "base_x_m", "abs", 0.01, "the trunk shifts back as the legs sag"),
    Check("stand", "total_foot_force_n", "rel", 0.01, "the weight, 147.3 N"),
    *(Check("stand", f"foot_force_n[{f}]", "rel", 0.05) for f in range(4)),
    # Dropped from 0.5 m.
    Check("drop", "first_contact_s", "abs", 0.0051, "one physics step"),
    Check("drop", "min_base_height_m", "abs", 0.01),
    Check("drop", "settled_height_m", "abs", 0.005),
    Check("drop", "peak_foot_force_n", "rel", 0.30, "one policy step's mean force"),
    Check("drop", "settle_time_s", "rel", 0.5, "into a 5 mm band: sensitive to the damping"),
    # The open-loop trots: speed within 20% (the aim), posture within stated bounds.
    *(
        c
        for t in ("trot_forward", "trot_backward")
        for c in (
            Check(t, "forward_speed_mps", "rel", 0.20),
            Check(t, "base_height_m", "abs", 0.01),
            Check(t, "pitch_range_rad", "abs", 0.03),
            Check(t, "roll_range_rad", "abs", 0.03),
            Check(t, "lateral_speed_mps", "abs", 0.05),
        )
    ),
    # Free floating, no gravity: the trunk's counter-rotation (inertia) and how fast the joint
    # gets there (armature).
    Check("free_float_roll", "roll_rad", "rel", 0.05),
    Check("free_float_roll", "joint_moved_rad", "abs", 0.005),
    Check("free_float_roll", "joint_moved_early_rad", "rel", 0.10),
    Check("free_float_pitch", "pitch_rad", "rel", 0.05),
    Check("free_float_pitch", "joint_moved_rad", "abs", 0.005),
    Check("free_float_pitch", "joint_moved_early_rad", "rel", 0.10),
]


LOW_ARMATURE = 0.0005
"""Armature (kg m^2) at which both engines run nearly without it."""

_ON_LINKS = "; agrees when MuJoCo carries the armature on the links as we do"
ARMATURE_MODEL_EXCEPTIONS: dict[tuple[str, str], str] = {
    ("robot", "whole_body_inertia[0]"): (
        "our 4 hips carry their 0.02 kg m^2 armature about x as link inertia: 0.2655 vs "
        "0.1855 kg m^2 (+0.080 = 4 x 0.02; MuJoCo's joint armature is no body inertia)" + _ON_LINKS
    ),
    ("robot", "whole_body_inertia[1]"): (
        "our 8 thighs and calves carry their armature about y as link inertia: 0.6529 vs "
        "0.4945 kg m^2 (+0.158 ~ 8 x 0.02)" + _ON_LINKS
    ),
    ("robot", "whole_body_inertia[2]"): (
        "link armature, joint axes not quite horizontal in the default pose: 0.5590 vs "
        "0.5574 kg m^2 (+0.3%)" + _ON_LINKS
    ),
    **{
        ("step_thigh", q): (
            "trunk held, the thigh joint also turns the calf's link armature (parallel axis): "
            "~0.04 kg m^2 against MuJoCo's 0.02; rise 0.096 vs 0.078 s, peak 0.195 vs 0.155 s, "
            "overshoot 0.148 vs 0.088" + _ON_LINKS
        )
        for q in ("rise_time_s", "peak_time_s", "overshoot")
    },
    **{
        ("step_calf", q): (
            "the calf's link armature reacts on the thigh (rigid inertia, not a geared rotor), "
            "which the thigh's PD lets swing: rise 0.070 vs 0.061 s, peak 0.195 vs 0.130 s, "
            "overshoot 0.086 vs 0.127" + _ON_LINKS
        )
        for q in ("rise_time_s", "peak_time_s", "overshoot")
    },
    ("free_float_roll", "roll_rad"): (
        "the swung hip's link armature carries angular momentum the trunk must balance: "
        "-0.193 vs -0.168 rad (+15%)" + _ON_LINKS
    ),
    ("free_float_roll", "joint_moved_early_rad"): (
        "the joint moves 0.290 vs 0.248 rad in the first 50 ms: with link armature part of the "
        "motion is the trunk turning the other way" + _ON_LINKS
    ),
    ("free_float_pitch", "pitch_rad"): (
        "the swung thighs' and calves' link armature carries angular momentum the trunk must "
        "balance: -0.187 vs -0.085 rad (2.2x)" + _ON_LINKS
    ),
}
"""Checks that fail at the nominal armature because of the armature model alone."""

LINK_ARMATURE_EXCEPTIONS: dict[tuple[str, str], str] = {
    ("trot_forward", "forward_speed_mps"): (
        "open-loop trot, nominal link armature in both: ours 0.28 m/s, MuJoCo 0.18 (0.20 with "
        "its stiffest contact, solref 0.01 s; ours 0.25 with 8 substeps); contact-model "
        "sensitive, the rest unexplained (the backward trot agrees: -0.294 vs -0.282)"
    ),
}
"""Checks that fail with the same (link) armature model in both engines, and why."""

LOW_ARMATURE_EXCEPTIONS: dict[tuple[str, str], str] = {
    ("step_calf", "peak_time_s"): (
        "armature 0.0005: the calf creeps onto a plateau (overshoot 0.0188 vs 0.0186, equal "
        "settled error), so the peak's time is the argmax of a flat trace: 0.395 s in ours, "
        "the trace's end (1 s) in MuJoCo"
    ),
    ("trot_forward", "forward_speed_mps"): (
        "open-loop trot, armature 0.0005: ours 0.61 m/s, MuJoCo 0.36 m/s; MuJoCo's soft "
        "contact is part of it (0.47 m/s at solref 0.01 s, its stiffest at 5 ms), friction "
        "settings are not (0.36-0.37 m/s with impratio 1, pyramidal cone, no-slip); the rest "
        "unexplained"
    ),
    ("trot_backward", "pitch_range_rad"): (
        "open-loop trot, armature 0.0005, a bouncing gait: ours 0.25 rad with 2 substeps, "
        "0.17 with 8 (MuJoCo 0.19): our solver's convergence"
    ),
    ("trot_backward", "roll_range_rad"): (
        "open-loop trot, armature 0.0005, a bouncing gait: ours 0.39 rad with 2 substeps, "
        "0.12 with 8; MuJoCo 0.07, 0.20 with its stiffest contact: solver- and "
        "contact-sensitive"
    ),
}
"""Checks that still fail with the armature nearly off (on the links in both), and why."""


ARTICULATED_SOLREF = (0.01, 1.0)
"""The articulated engine's contact and stop time constant (twice the 5 ms step; MuJoCo's own
default is 0.02 s), given to MuJoCo for the comparison with it."""

ARTICULATED_CONE = "pyramidal"
"""MuJoCo's friction cone in the comparison with the articulated engine. Our engine bounds each
tangent direction apart (a box cone, solved by Gauss-Seidel); the only figure the cone moves is
the open-loop forward trot's speed, which spreads over 0.309-0.376 m/s across MuJoCo's own
solvers and cones (:func:`test_articulated_trot_lies_within_mujocos_solver_spread`). Against the
elliptic cone and Newton solver it is 0.395 against 0.318 (24%); decision record 0024."""

ARTICULATED_EXCEPTIONS: dict[tuple[str, str], str] = {}
"""Checks the articulated engine (``physics.engine = "articulated"``, armature on the joints,
the URDF's inertias) fails against MuJoCo with the same armature model, and why: none."""


def _value(result: dict[str, Any], quantity: str) -> float:
    if quantity.endswith("]"):
        name, index = quantity[:-1].split("[")
        value = result[name][int(index)]
    else:
        value = result[quantity]
    return math.nan if value is None else float(value)  # JSON null: not reached (rise time)


def _results(
    binary: Path, armature: float | None = None, on_links: bool = False
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Ours and MuJoCo's figures; ``on_links``: MuJoCo carries the armature as we do."""
    names = list(scenarios.SCENARIOS)
    options = PhysicsOptions(armature_on_links=on_links)
    if armature is not None:
        options = dataclasses.replace(options, armature=armature)
    return (
        run_ours(binary, names, armature, engine="rapier"),
        scenarios.run(names, options),
    )


@pytest.fixture(scope="module")
def results(crosscheck_bin: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    return _results(crosscheck_bin)


@pytest.fixture(scope="module")
def results_articulated(crosscheck_bin: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """The articulated engine against MuJoCo with the same armature model and inertias."""
    names = list(scenarios.SCENARIOS)
    options = PhysicsOptions(min_link_inertia=0.0, solref=ARTICULATED_SOLREF, cone=ARTICULATED_CONE)
    return (
        run_ours(crosscheck_bin, names, engine="articulated"),
        scenarios.run(names, options),
    )


@pytest.fixture(scope="module")
def results_link_armature(crosscheck_bin: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    return _results(crosscheck_bin, on_links=True)


@pytest.fixture(scope="module")
def results_low_armature(crosscheck_bin: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    return _results(crosscheck_bin, LOW_ARMATURE, on_links=True)


def _cases(exceptions: dict[tuple[str, str], str]) -> list[Any]:
    cases = []
    for c in CHECKS:
        why = exceptions.get((c.scenario, c.quantity))
        marks = [pytest.mark.xfail(reason=why, strict=True)] if why else []
        cases.append(pytest.param(c, marks=marks, id=f"{c.scenario}.{c.quantity}"))
    return cases


def _assert_agrees(results: tuple[dict[str, Any], dict[str, Any]], check: Check) -> None:
    ours, theirs = results
    a = _value(ours[check.scenario], check.quantity)
    b = _value(theirs[check.scenario], check.quantity)
    err = check.error(a, b)
    assert err <= check.tolerance, (
        f"{check.scenario} {check.quantity}: ours {a:.5g}, MuJoCo {b:.5g} "
        f"({check.kind} error {err:.3g} > {check.tolerance})"
    )


@pytest.mark.parametrize("name", [n for n in scenarios.SCENARIOS if n != "robot"])
def test_both_engines_run_the_same_scenario(results, name):
    ours, theirs = results
    a, b = ours[name]["params"], theirs[name]["params"]
    assert set(a) == set(b), name
    for key in a:
        np.testing.assert_allclose(a[key], b[key], rtol=1e-6, err_msg=f"{name}.{key}")


def test_both_engines_load_one_model(results):
    ours, theirs = results
    a, b = ours["robot"], theirs["robot"]
    for key in ("default_q", "effort", "foot_radius"):
        np.testing.assert_allclose(a[key], b[key], atol=1e-6, err_msg=key)
    for key in (
        "kp",
        "kd",
        "armature",
        "joint_damping",
        "joint_friction",
        "min_link_inertia",
        "dt",
    ):
        assert a[key] == pytest.approx(b[key], abs=1e-7), key
    np.testing.assert_allclose(a["foot_pos_default"], b["foot_pos_default"], atol=1e-5)


@pytest.mark.parametrize("check", _cases(ARMATURE_MODEL_EXCEPTIONS))
def test_figure_agrees(results, check):
    """Nominal physics; MuJoCo models the armature its own way (on the joint coordinate)."""
    _assert_agrees(results, check)


@pytest.mark.parametrize("check", _cases(LINK_ARMATURE_EXCEPTIONS))
def test_figure_agrees_with_link_armature(results_link_armature, check):
    """Nominal physics; MuJoCo adds the armature to the links' inertia, as we do."""
    _assert_agrees(results_link_armature, check)


@pytest.mark.parametrize("check", _cases(LOW_ARMATURE_EXCEPTIONS))
def test_figure_agrees_at_low_armature(results_low_armature, check):
    """Both engines with armature 0.0005 (on the links): isolates model, contacts, actuation."""
    _assert_agrees(results_low_armature, check)


@pytest.mark.parametrize("check", _cases(ARTICULATED_EXCEPTIONS))
def test_figure_agrees_articulated(results_articulated, check):
    """The articulated engine: armature on the joint coordinate, as MuJoCo's (issue 34)."""
    _assert_agrees(results_articulated, check)


def test_articulated_trot_lies_within_mujocos_solver_spread(results_articulated):
    """The forward trot's speed is a property of the contact solver as much as of the robot:
    MuJoCo's own three solvers and two cones spread it by a fifth. Ours must lie within that
    spread widened by the trot's 20% tolerance, whichever MuJoCo setting it is compared with."""
    ours, _ = results_articulated
    speeds = {}
    for solver in ("newton", "cg", "pgs"):
        for cone in ("elliptic", "pyramidal"):
            options = PhysicsOptions(
                min_link_inertia=0.0, solref=ARTICULATED_SOLREF, cone=cone, solver=solver
            )
            trot = scenarios.run(["trot_forward"], options)["trot_forward"]
            speeds[(solver, cone)] = trot["forward_speed_mps"]
    low, high = min(speeds.values()), max(speeds.values())
    # Measured 2026-11-26 (MuJoCo 4.0.0): 0.309 (cg, elliptic) to 0.376 (pyramidal, any solver).
    assert high / low > 1.1, speeds
    assert 0.8 * low <= ours["trot_forward"]["forward_speed_mps"] <= 1.2 * high, speeds


def test_articulated_engine_loads_the_urdf_model(results_articulated):
    ours, theirs = results_articulated
    for key in ("kp", "kd", "armature", "joint_damping", "joint_friction", "min_link_inertia"):
        assert ours["robot"][key] == pytest.approx(theirs["robot"][key], abs=1e-7), key


def _verdict(check: Check, error: float, exceptions: dict[tuple[str, str], str]) -> str:
    ok = error <= check.tolerance
    if (check.scenario, check.quantity) in exceptions:
        return "xfail" if not ok else "XPASS"
    return "pass" if ok else "FAIL"


def table(binary: Path, armature: float | None = None) -> str:
    """The cross-check table in Markdown.

    Ours against MuJoCo with its own (joint) armature and with the armature on the links as
    ours: values, ratios, the tolerance and pass / xfail (an expected failure of the tests) /
    FAIL / XPASS (an expected failure that passed).
    """
    ours, joint = _results(binary, armature)
    _, link = _results(binary, armature, on_links=True)
    joint_exc = ARMATURE_MODEL_EXCEPTIONS if armature is None else {}
    link_exc = LINK_ARMATURE_EXCEPTIONS if armature is None else LOW_ARMATURE_EXCEPTIONS
    lines = [
        "| scenario | quantity | ours | MuJoCo | ratio | MuJoCo, link armature | ratio "
        "| tolerance | vs MuJoCo | vs link armature |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for c in CHECKS:
        a = _value(ours[c.scenario], c.quantity)
        b = _value(joint[c.scenario], c.quantity)
        bl = _value(link[c.scenario], c.quantity)
        ratio = a / b if b != 0 else math.nan
        ratio_l = a / bl if bl != 0 else math.nan
        tol = f"{c.tolerance:g}" + ("" if c.kind == "abs" else " rel")
        lines.append(
            f"| {c.scenario} | {c.quantity} | {a:.4g} | {b:.4g} | {ratio:.3f} | {bl:.4g} "
            f"| {ratio_l:.3f} | {tol} | {_verdict(c, c.error(a, b), joint_exc)} "
            f"| {_verdict(c, c.error(a, bl), link_exc)} |"
        )
    return "\n".join(lines)


if __name__ == "__main__":
    import os
    import sys

    default = Path(__file__).resolve().parents[1] / "target" / "release" / "unigait-crosscheck"
    driver = Path(os.environ.get("UNIGAIT_CROSSCHECK_BIN", default))
    print(table(driver, float(sys.argv[1]) if len(sys.argv) > 1 else None))
