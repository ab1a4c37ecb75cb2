"""The package's build step: the gRPC stubs from ../proto, the data files from ../assets.

``build_py`` (named in pyproject.toml) generates the stubs and links the recipes, milestones
and Go2 URDF before the usual build: the proto stays the single source of the wire format and
assets/ the single home of the data files. Nothing runs on import: only a build (``pip
install``, editable or not, ``pip wheel``, ``python -m build``) runs :class:`BuildPyWithStubs`.
The generated modules land in ``src/unigait/_proto/v1/`` (git-ignored), and the packages they
add join the build's list there. This module is not installed. Set ``UNIGAIT_PROTO_DIR`` to
build from a proto tree elsewhere.
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
from pathlib import Path

from setuptools.command.build_py import build_py

#: client-py/ (this file is in its src/).
HERE = Path(__file__).resolve().parents[1]
#: Packages the build step creates, which discovery at configuration time cannot see yet. The
#: data folders under _assets are named too: setuptools warns about (and plans to drop) data in
#: an importable folder that is not a listed package.
GENERATED_PACKAGES = (
    "unigait._proto",
    "unigait._proto.v1",
    "unigait._assets",
    "unigait._assets.go2",
    "unigait._assets.recipes",
)
#: The project's data files the package carries (recipes, milestones, the Go2 robot model: the
#: URDF with its licence and notes, no meshes): their home is assets/.
ASSETS = ("recipes", "milestones.toml", "go2")
ASSETS_DIR = HERE / "src" / "unigait" / "_assets"
PROTO_FILE = Path("unigait/v1/unigait.proto")
OUT_DIR = HERE / "src" / "unigait" / "_proto" / "v1"


def _proto_root() -> Path:
    root = Path(os.environ.get("UNIGAIT_PROTO_DIR", HERE.parent / "proto"))
    return root.resolve()


def generate_stubs() -> None:
    """Run grpc_tools.protoc on unigait/v1/unigait.proto into src/unigait/_proto/v1/."""
    root = _proto_root()
    source = root / PROTO_FILE
    if not source.is_file():
        if (OUT_DIR / "unigait_pb2.py").is_file():
            return  # building from an sdist that already carries the stubs
        raise RuntimeError(f"unigait: proto file not found at {source} (set UNIGAIT_PROTO_DIR)")
    import grpc_tools
    from grpc_tools import protoc

    include = Path(grpc_tools.__file__).parent / "_proto"
    with tempfile.TemporaryDirectory() as tmp:
        args = [
            "grpc_tools.protoc",
            f"-I{root}",
            f"-I{include}",
            f"--python_out={tmp}",
            f"--pyi_out={tmp}",
            f"--grpc_python_out={tmp}",
            str(source),
        ]
        if protoc.main(args) != 0:
            raise RuntimeError(f"unigait: protoc failed on {source}")
        OUT_DIR.mkdir(parents=True, exist_ok=True)
        generated = Path(tmp) / PROTO_FILE.parent
        for path in generated.iterdir():
            text = path.read_text()
            # The stubs import each other by proto path (`unigait.v1`), which would clash with
            # this package: point them at their real location.
            text = re.sub(
                r"^from unigait\.v1 import",
                "from unigait._proto.v1 import",
                text,
                flags=re.MULTILINE,
            )
            (OUT_DIR / path.name).write_text(text)
    for pkg in (OUT_DIR.parent, OUT_DIR):
        (pkg / "__init__.py").write_text('"""Generated from proto/ at build time."""\n')
    shutil.rmtree(HERE / "build" / "lib" / "unigait" / "_proto", ignore_errors=True)


def link_assets() -> None:
    """Link ../assets/{recipes,milestones.toml,go2} into src/unigait/_assets/ (git-ignored).

    A link, not a copy: an editable install then reads the repository's files as they change,
    and a wheel's build copies what the link points at.
    """
    ASSETS_DIR.mkdir(parents=True, exist_ok=True)
    (ASSETS_DIR / "__init__.py").write_text('"""Linked from ../assets at build time."""\n')
    for name in ASSETS:
        source = HERE.parent / "assets" / name
        link = ASSETS_DIR / name
        if not source.exists():
            if link.exists():
                continue  # building from an sdist that already carries them
            raise RuntimeError(f"unigait: {source} not found")
        if link.is_symlink() or link.is_file():
            link.unlink()
        elif link.is_dir():
            shutil.rmtree(link)
        link.symlink_to(os.path.relpath(source, ASSETS_DIR))


class BuildPyWithStubs(build_py):
    """``build_py`` that generates the stubs and links the data files first."""

    def run(self) -> None:
        """Generate the stubs, link the assets, add their packages, then build as usual."""
        generate_stubs()
        link_assets()
        # A fresh checkout has none of them when setuptools discovers the packages.
        packages = list(self.packages or [])
        packages += [p for p in GENERATED_PACKAGES if p not in packages]
        self.packages = packages
        self.distribution.packages = packages
        super().run()
