"""A mesh reader that needs a Python package which is not installed says so, naming the package to install, instead
of calling the mesh file unreadable (warp_verlet/geometry/mesh_io.read_mesh). Each case makes the module missing the way an
install without it would: None in sys.modules, which makes every import of it raise ModuleNotFoundError."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from warp_verlet.geometry.mesh_cloth import MeshError
from warp_verlet.geometry.mesh_io import read_mesh

ROOT = Path(__file__).resolve().parent.parent
ASSETS = ROOT / "scenes" / "assets"


@pytest.mark.slow
def test_tablecloth_without_pillow_names_pillow():
    """trimesh imports Pillow when it is itself imported and, when that fails, raises the import error again from
    its OBJ loader for an OBJ with UVs (the tablecloth's). A fresh interpreter, so that trimesh is imported after
    Pillow is made missing, as on an install without it."""
    code = textwrap.dedent("""
        import sys
        sys.modules["PIL"] = None
        from warp_verlet.errors import SceneError
        from warp_verlet.input.scene import load_scene
        try:
            load_scene("scenes/tablecloth.toml")
        except SceneError as err:
            print(err.key)
            print(err.problem)
        else:
            print("loaded")
    """)
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    key, problem = done.stdout.strip().splitlines()[-2:]
    assert key == "cloth[0].mesh"
    assert problem == ("reading tablecloth.obj needs the Python package Pillow, which is not installed "
                       "(pip install pillow)")


def test_usd_mesh_without_usd_core_names_usd_core(monkeypatch):
    monkeypatch.setitem(sys.modules, "pxr", None)
    with pytest.raises(MeshError) as info:
        read_mesh(ASSETS / "curtain.usda", "/Set/Window/Curtain", np.eye(4))
    assert str(info.value) == ("reading curtain.usda needs the Python package usd-core, which is not installed "
                               "(pip install usd-core)")


@pytest.mark.parametrize("error, package", [
    (ModuleNotFoundError("No module named 'networkx'"), "networkx"),  # re-raised from its message alone: no name
    (ModuleNotFoundError("No module named 'PIL.Image'", name="PIL.Image"), "Pillow"),  # a submodule: its package
    (ModuleNotFoundError("import of yaml halted; None in sys.modules"), "PyYAML"),
])
def test_any_missing_module_inside_a_reader_names_its_package(monkeypatch, error, package):
    import trimesh

    def load(*args, **kwargs):
        raise error

    monkeypatch.setattr(trimesh, "load", load)
    with pytest.raises(MeshError) as info:
        read_mesh(ASSETS / "tablecloth.obj", None, np.eye(4))
    assert str(info.value) == (f"reading tablecloth.obj needs the Python package {package}, which is not installed "
                               f"(pip install {package.lower()})")


def test_a_damaged_file_is_still_a_mesh_that_cannot_be_read(tmp_path):
    """The other failures of the loader keep their message about the file."""
    broken = tmp_path / "broken.glb"
    broken.write_bytes(b"glTF not really")
    with pytest.raises(MeshError, match=r"broken\.glb: cannot read the mesh"):
        read_mesh(broken, None, np.eye(4))
