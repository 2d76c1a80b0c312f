"""A USD asset's own files are inputs too: no output (``run -o``, a scene's cache or override layer, ``live
--record``) may replace a layer the asset composes (sublayers, references, payloads, recursively), and an asset
whose composition is broken (cycles, missing layers, a layer that is not USD) is refused with one plain error
that names it, without USD's C++ source locations, and nothing written."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from mesh_files import grid_mesh, write_usd_mesh
from warp_verlet.apps.cli import main

# The asset: top.usda takes the cloth from its sublayer base.usda, has a second sublayer, and a prim that
# references ref.usda, whose prim has a payload in pay.usda.
TOP = """#usda 1.0
(
    defaultPrim = "Set"
    subLayers = [@./sub.usda@, @./base.usda@]
)
over "Set" {
    def Xform "Prop" (prepend references = @./ref.usda@) {}
}
"""
REF = '#usda 1.0\n(\n    defaultPrim = "Thing"\n)\ndef Xform "Thing" (prepend payload = @./pay.usda@) {}\n'
PAY = '#usda 1.0\n(\n    defaultPrim = "Inner"\n)\ndef Xform "Inner" {}\n'
SUB = "#usda 1.0\n"
DEPENDENCIES = ("sub.usda", "base.usda", "ref.usda", "pay.usda")  # sublayer, sublayer, reference, its payload


def scene_text(mesh: str, output: str, kind: str = "cache") -> str:
    return (f'[simulation]\nframes = 2\n[output]\npath = "{output}"\nkind = "{kind}"\n'
            f'[[cloth]]\nname = "curtain"\nmesh = "{mesh}"\nprim = "/Set/Cloth"\n')


@pytest.fixture
def asset(tmp_path, monkeypatch) -> Path:
    monkeypatch.chdir(tmp_path)
    points, faces = grid_mesh(3, 4)
    write_usd_mesh(tmp_path / "base.usda", points, faces)
    for name, text in (("top.usda", TOP), ("ref.usda", REF), ("pay.usda", PAY), ("sub.usda", SUB)):
        (tmp_path / name).write_text(text)
    return tmp_path / "top.usda"


def contents(directory: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(directory.iterdir()) if p.is_file()}


def run(*args) -> int:
    return main(["run", *map(str, args), "--device", "cpu", "-q"])


@pytest.mark.parametrize("dependency", DEPENDENCIES)
def test_run_o_may_not_replace_a_layer_the_asset_composes(asset, capfd, dependency):
    (asset.parent / "scene.toml").write_text(scene_text("top.usda", "out.usdc"))
    before = contents(asset.parent)
    assert run("scene.toml", "-o", dependency) == 2
    err = capfd.readouterr().err
    assert f"would overwrite the input file {asset.parent / dependency}" in err
    assert contents(asset.parent) == before  # nothing written, nothing replaced


@pytest.mark.parametrize("kind", ["cache", "override"])
def test_a_scene_output_may_not_replace_a_layer_the_asset_composes(asset, capfd, kind):
    """The payload of a reference, two arcs below the asset, as the scene's own output path."""
    (asset.parent / "scene.toml").write_text(scene_text("top.usda", "pay.usda", kind))
    before = contents(asset.parent)
    assert run("scene.toml") == 2
    assert f"would overwrite the input file {asset.parent / 'pay.usda'}" in capfd.readouterr().err
    assert contents(asset.parent) == before


def test_live_record_may_not_replace_a_layer_the_asset_composes(asset, capfd):
    (asset.parent / "scene.toml").write_text(scene_text("top.usda", "out.usdc"))
    before = contents(asset.parent)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    assert main(["live", "scene.toml", "--device", "cpu", "--record", "ref.usda", "--port", str(port),
                 "--seconds", "1"]) == 2
    err = capfd.readouterr().err
    assert "--record" in err and f"would overwrite the input file {asset.parent / 'ref.usda'}" in err
    assert contents(asset.parent) == before


# (the layers to write, the asset, what the error must say): each asset's composition is broken.
BROKEN = {
    "a sublayer that is its own file": ({"self.usda": '#usda 1.0\n(\n    subLayers = [@./self.usda@, @./base.usda@]\n)\n'},
                                        "self.usda", "Sublayer hierarchy with root layer @self.usda@ has cycles"),
    "two layers that sublayer each other": ({"a.usda": '#usda 1.0\n(\n    subLayers = [@./b.usda@, @./base.usda@]\n)\n',
                                             "b.usda": '#usda 1.0\n(\n    subLayers = [@./a.usda@]\n)\n'},
                                            "a.usda", "b.usda@ has cycles"),
    "a prim that references its own file": (
        {"selfref.usda": '#usda 1.0\n(\n    defaultPrim = "Set"\n    subLayers = [@./base.usda@]\n)\n'
                         'over "Set" {\n    over "Cloth" (prepend references = @./selfref.usda@) {}\n}\n'},
        "selfref.usda", "Cycle detected"),
    "a missing sublayer": ({"missing.usda": '#usda 1.0\n(\n    subLayers = [@./gone.usda@, @./base.usda@]\n)\n'},
                           "missing.usda", "Could not load sublayer @{dir}/gone.usda@ of layer @missing.usda@"),
    "a sublayer that is not a USD file": (
        {"passwd.usda": '#usda 1.0\n(\n    subLayers = [@/etc/passwd@, @./base.usda@]\n)\n'},
        "passwd.usda", "Could not load sublayer @/etc/passwd@ of layer @passwd.usda@ -- Cannot determine file format"),
    "a torn layer in a variant that is not selected": (
        {"variant.usda": '#usda 1.0\n(\n    defaultPrim = "Set"\n    subLayers = [@./base.usda@]\n)\n'
                         'over "Set" (\n    variants = { string look = "plain" }\n    prepend variantSets = "look"\n) {\n'
                         '    variantSet "look" = {\n        "plain" {}\n'
                         '        "fancy" {\n            def Xform "Trim" (prepend references = @./torn.usda@) {}\n'
                         '        }\n    }\n}\n',
         "torn.usda": '#usda 1.0\ndef Xform "Trim" {\n    double3 xformOp:translate = (0, 0,\n'},
        "variant.usda", "a layer it names cannot be read ({dir}/torn.usda:4:1: parse error"),
}


@pytest.mark.parametrize("case", list(BROKEN))
@pytest.mark.parametrize("command", ["validate", "run"])
def test_a_broken_composition_is_one_plain_error(asset, capfd, case, command):
    layers, mesh, problem = BROKEN[case]
    for name, text in layers.items():
        (asset.parent / name).write_text(text)
    (asset.parent / "scene.toml").write_text(scene_text(mesh, "out.usdc"))
    before = contents(asset.parent)
    args = ["validate", "scene.toml"] if command == "validate" else ["run", "scene.toml", "--device", "cpu", "-q"]
    assert main(args) == 2
    out, err = capfd.readouterr()  # file descriptors: USD's C++ diagnostics would land there
    lines = err.strip().splitlines()
    assert len(lines) == 1, err  # one error, no warning beside it
    assert lines[0].startswith(f"error: scene.toml: cloth[0].mesh: {mesh}: a broken USD asset: ")
    assert problem.format(dir=asset.parent) in lines[0]
    assert ".cpp" not in out + err and "line " not in err and "0x" not in err and "skipping" not in err
    assert contents(asset.parent) == before


def test_a_usd_parse_error_names_no_cpp_symbol(asset, capfd):
    (asset.parent / "torn.usda").write_text('#usda 1.0\ndef Mesh "Cloth" {\n    point3f[] points = [(0, 0,\n')
    (asset.parent / "scene.toml").write_text(scene_text("torn.usda", "out.usdc"))
    assert main(["validate", "scene.toml"]) == 2
    err = capfd.readouterr().err
    assert "torn.usda: cannot open as USD (" in err and "parse error" in err
    assert "pxrInternal" not in err and "pxrReserved" not in err and ".cpp" not in err and ".h " not in err


def test_a_layer_the_asset_names_but_does_not_compose_yet_is_an_input_and_a_plain_warning(asset, capfd):
    """A reference in a variant that is not selected, to a file that does not exist: the asset composes without
    it (so it is no error), but a cache written there would become part of the asset the next time that variant
    is chosen. USD's report of the unresolved path is one plain warning."""
    (asset.parent / "variant.usda").write_text(
        '#usda 1.0\n(\n    defaultPrim = "Set"\n    subLayers = [@./base.usda@]\n)\n'
        'over "Set" (\n    variants = { string look = "plain" }\n    prepend variantSets = "look"\n) {\n'
        '    variantSet "look" = {\n        "plain" {}\n'
        '        "fancy" {\n            def Xform "Trim" (prepend references = @./later.usda@) {}\n        }\n    }\n}\n')
    (asset.parent / "scene.toml").write_text(scene_text("variant.usda", "out.usdc"))
    assert main(["validate", "scene.toml"]) == 0
    err = capfd.readouterr().err
    assert err.strip() == (f"warning: variant.usda: Failed to resolve reference @./later.usda@ with computed asset "
                           f"path @{asset.parent / 'later.usda'}@ found in layer @{asset.parent / 'variant.usda'}@.")
    before = contents(asset.parent)
    assert run("scene.toml", "-o", "later.usda") == 2
    assert f"would overwrite the input file {asset.parent / 'later.usda'}" in capfd.readouterr().err
    assert contents(asset.parent) == before
