"""Training presets, kept as TOML files: ``python -m unigait train --preset NAME``."""

from __future__ import annotations

from importlib import resources
from pathlib import Path


def names() -> list[str]:
    """The presets shipped with the package."""
    folder = resources.files(__name__)
    return sorted(
        p.name.removesuffix(".toml") for p in folder.iterdir() if p.name.endswith(".toml")
    )


def path(name: str) -> Path:
    """The TOML file of preset ``name``.

    Raises:
        KeyError: No such preset (the message lists the known ones).
    """
    if name not in names():
        raise KeyError(f"unknown preset {name!r}; known: {names()}")
    return Path(str(resources.files(__name__).joinpath(f"{name}.toml")))


def overrides_of(name: str) -> list[str]:
    """Preset ``name`` as ``section.key=value`` overrides (applied before the user's own)."""
    import json
    import tomllib

    values = tomllib.loads(path(name).read_text())
    return [
        f"{section}.{key}={json.dumps(value)}"
        for section, entries in values.items()
        for key, value in entries.items()
    ]
