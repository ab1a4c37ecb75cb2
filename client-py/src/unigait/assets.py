"""The project's data files that the package carries: training recipes, milestones, the Go2.

They have one home, ``assets/`` in the repository (``assets/recipes/*.toml``,
``assets/milestones.toml``, ``assets/go2/go2.urdf``), which the Rust crates read too. The
package's build step (``client-py/src/unigait_build.py``) links them into ``unigait/_assets/``
for an editable install and copies them into a wheel, so an installed package reads the same
files.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path


def assets_dir() -> Path:
    """The package's ``_assets`` folder (recipes, milestones, the Go2 model)."""
    return Path(str(resources.files("unigait").joinpath("_assets")))


def recipes_dir() -> Path:
    """Where the packaged recipes live."""
    return assets_dir() / "recipes"


def milestones_file() -> Path:
    """The packaged milestones file."""
    return assets_dir() / "milestones.toml"


def go2_urdf() -> Path:
    """The packaged Go2 URDF (the server's robot; its licence and README sit beside it)."""
    return assets_dir() / "go2" / "go2.urdf"
