"""The package's dependencies: ranges in pyproject.toml, exact pins in constraints.txt.

Every requirement of the package and its extras has one pin, inside its range, and nothing is
pinned that the package does not ask for; extra names are normalised (PEP 685).
"""

import tomllib
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

CLIENT_PY = Path(__file__).resolve().parents[1]


def _project() -> dict:
    return tomllib.loads((CLIENT_PY / "pyproject.toml").read_text())["project"]


def _requirements() -> list[Requirement]:
    project = _project()
    lines = list(project["dependencies"])
    for extra in project["optional-dependencies"].values():
        lines += extra
    return [Requirement(line) for line in lines]


def _pins() -> dict[str, Version]:
    pins = {}
    for raw in (CLIENT_PY / "constraints.txt").read_text().splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        name, _, version = line.partition("==")
        assert version, f"not an exact pin: {raw!r}"
        assert canonicalize_name(name) not in pins, f"pinned twice: {name}"
        pins[canonicalize_name(name)] = Version(version)
    return pins


def test_every_requirement_has_one_pin_inside_its_range():
    pins = _pins()
    for req in _requirements():
        name = canonicalize_name(req.name)
        assert name in pins, f"{req.name} has no pin in constraints.txt"
        assert req.specifier.contains(pins[name], prereleases=True), (
            f"the pin {req.name}=={pins[name]} is outside the package's range {req.specifier}"
        )
    assert set(pins) == {canonicalize_name(r.name) for r in _requirements()}, "stray pins"


def test_requirements_are_ranges_not_pins():
    for req in _requirements():
        assert not any(s.operator in ("==", "===") for s in req.specifier), (
            f"{req}: pin it in constraints.txt, give the package a range"
        )


def test_extra_names_are_normalised():
    for extra in _project()["optional-dependencies"]:
        assert extra == canonicalize_name(extra), extra
