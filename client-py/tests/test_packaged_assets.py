"""The package carries the data its features need (recipes, milestones, the Go2 URDF).

``scripts/test.sh`` runs this file a second time against a non-editable install of client-py
(``UNIGAIT_INSTALLED_ROOT`` names it), so a file the wheel leaves out fails CI.
"""

import os
from pathlib import Path

import numpy as np
import pytest

import unigait
from unigait.assets import go2_urdf, milestones_file, recipes_dir
from unigait.milestones import load_milestones
from unigait.recipes import load_recipe, recipe_names

PACKAGE = Path(unigait.__file__).resolve().parent


def test_the_run_under_test_is_the_installed_copy():
    root = os.environ.get("UNIGAIT_INSTALLED_ROOT")
    if not root:
        pytest.skip("UNIGAIT_INSTALLED_ROOT unset: the editable install is under test")
    assert PACKAGE.is_relative_to(Path(root).resolve()), PACKAGE
    # A wheel copies the files; only the editable install links to assets/.
    assert not (PACKAGE / "_assets" / "go2").is_symlink()


def test_recipes_and_milestones_come_from_the_package():
    assert recipes_dir().is_relative_to(PACKAGE / "_assets")
    assert "unified_terrain" in recipe_names()
    assert len(load_recipe("unified_terrain").stages) >= 1
    assert milestones_file().is_file()
    assert {"M1", "M2"} <= set(load_milestones())


def test_the_go2_urdf_is_package_data_with_its_licence():
    urdf = go2_urdf()
    assert urdf.is_file()
    assert urdf.parent == PACKAGE / "_assets" / "go2"
    assert (urdf.parent / "LICENSE-unitree.txt").is_file()
    assert (urdf.parent / "README.md").is_file()
    # Collision and visuals are primitives: the URDF alone is the whole model.
    assert "<mesh" not in urdf.read_text()


def test_the_packaged_go2_compiles_in_mujoco(monkeypatch):
    pytest.importorskip("mujoco")
    from unigait.mujoco.model import build_model, find_go2_urdf

    monkeypatch.delenv("UNIGAIT_GO2_URDF", raising=False)
    assert find_go2_urdf() == go2_urdf()
    go2 = build_model()
    # A free base (7 qpos, 6 dof) and 12 hinges.
    assert (go2.model.nq, go2.model.nv, go2.model.njnt) == (19, 18, 13)
    # The URDF's masses: base 6.923 + 4 legs x (hip 0.678 + thigh 1.152 + calf 0.194) kg.
    assert go2.model.body_mass.sum() == pytest.approx(15.019, abs=1e-9)
    np.testing.assert_allclose(go2.effort, [23.7, 23.7, 35.55] * 4)


def test_the_crosscheck_driver_is_found_by_name_not_by_the_checkout(monkeypatch, tmp_path):
    """$UNIGAIT_CROSSCHECK_BIN, else `unigait-crosscheck` on PATH; never a walk up the tree (run
    from a checkout with a built driver, nothing else on PATH: still a clear error)."""
    pytest.importorskip("mujoco")
    from unigait.mujoco.crosscheck import find_crosscheck_binary

    monkeypatch.delenv("UNIGAIT_CROSSCHECK_BIN", raising=False)
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(FileNotFoundError, match="UNIGAIT_CROSSCHECK_BIN"):
        find_crosscheck_binary()
    driver = tmp_path / "unigait-crosscheck"
    driver.write_text("#!/bin/sh\n")
    driver.chmod(0o755)
    assert find_crosscheck_binary() == driver
    monkeypatch.setenv("UNIGAIT_CROSSCHECK_BIN", "/opt/x/crosscheck")
    assert find_crosscheck_binary() == Path("/opt/x/crosscheck")
