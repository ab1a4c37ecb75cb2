"""The project's data files that the package carries: training recipes and milestones.

They have one home, ``assets/`` in the repository (``assets/recipes/*.toml``,
``assets/milestones.toml``), which a Rust learner reads too. The package's build (``setup.py``)
links them into ``unigait/_assets/`` for an editable install and copies them into a wheel, so an
installed package reads the same files.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path


def assets_dir() -> Path:
    """The package's ``_assets`` folder (recipes and milestones)."""
    return Path(str(resources.files("unigait").joinpath("_assets")))


def recipes_dir() -> Path:
    """Where the packaged recipes live."""
    return assets_dir() / "recipes"


def milestones_file() -> Path:
    """The packaged milestones file."""
    return assets_dir() / "milestones.toml"
