"""``thrsim mesh`` through the real console script: help, JSON summaries, reading and writing."""

from __future__ import annotations

import json

import meshio
import pytest

HAND_INP = """*HEADING
hand-written ABAQUS deck: a unit cube split into five C3D4 tetrahedra
*NODE
1, 0.0, 0.0, 0.0
2, 1.0, 0.0, 0.0
3, 0.0, 1.0, 0.0
4, 1.0, 1.0, 0.0
5, 0.0, 0.0, 1.0
6, 1.0, 0.0, 1.0
7, 0.0, 1.0, 1.0
8, 1.0, 1.0, 1.0
*ELEMENT, TYPE=C3D4, ELSET=BONE
1, 2, 3, 5, 8
2, 1, 2, 3, 5
3, 4, 3, 2, 8
4, 6, 2, 5, 8
5, 7, 5, 3, 8
*NSET, NSET=FIXED
1, 2, 3, 4
*NSET, NSET=TOP
5, 6, 7, 8
"""


def one_json(result) -> dict:
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)  # the whole of stdout is one JSON object


def test_help(thrsim):
    top = thrsim("--help")
    assert top.returncode == 0 and "mesh" in top.stdout
    sub = thrsim("mesh", "--help")
    assert sub.returncode == 0
    for flag in ("--element-size", "--side", "--from", "--out", "--json"):
        assert flag in sub.stdout


def test_version(thrsim_inprocess):
    from thrsim import __version__

    result = thrsim_inprocess("--version")
    assert (result.returncode, result.stdout.strip()) == (0, __version__)


def test_default_mesh_right_and_left(thrsim_inprocess):
    thrsim = thrsim_inprocess
    right = one_json(thrsim("mesh", "--json"))
    assert abs(right["elements"] - 20406) <= 0.1 * 20406
    assert right["min_volume_mm3"] > 0 and right["quality"]["inverted"] == 0
    assert right["edges"] > right["elements"]
    assert right["volume_mm3"] == pytest.approx(362.4, rel=0.02)
    left = one_json(thrsim("mesh", "--side", "left", "--json"))
    for key in ("elements", "nodes", "edges", "boundary_faces", "fixed_nodes", "node_sets"):
        assert left[key] == right[key]
    assert left["min_volume_mm3"] > 0
    assert left["volume_mm3"] == pytest.approx(right["volume_mm3"])
    assert left["bounding_box_mm"]["min"][0] == pytest.approx(-right["bounding_box_mm"]["max"][0])


def test_table_output_without_json(thrsim_inprocess):
    result = thrsim_inprocess("mesh", "--element-size", "1.2")
    assert result.returncode == 0, result.stderr
    assert "bone mesh" in result.stdout and "quality" in result.stdout


def test_hand_written_inp_agrees_with_meshio(thrsim, tmp_path):
    path = tmp_path / "cube.inp"
    path.write_text(HAND_INP)
    reference = meshio.read(path)
    summary = one_json(thrsim("mesh", "--from", str(path), "--json"))
    assert summary["elements"] == sum(len(block.data) for block in reference.cells if block.type == "tetra") == 5
    assert summary["nodes"] == len(reference.points) == 8
    assert summary["edges"] == 4 and summary["boundary_faces"] == 12
    assert summary["volume_mm3"] == pytest.approx(1.0)
    assert summary["fixed_nodes"] == 4 and summary["node_sets"] == {"TOP": 4}


@pytest.mark.parametrize("suffix", [".vtu", ".msh", ".inp", ".h5"])
def test_out_round_trip(thrsim_inprocess, tmp_path, suffix):
    thrsim = thrsim_inprocess
    out = tmp_path / f"patch{suffix}"
    written = one_json(thrsim("mesh", "--element-size", "1.2", "--out", str(out), "--json"))
    assert written["out"] == str(out)
    assert [p.name for p in tmp_path.iterdir()] == [out.name]
    read = one_json(thrsim("mesh", "--from", str(out), "--json"))
    for key in ("elements", "nodes", "edges", "fixed_nodes", "node_sets"):
        assert read[key] == written[key]
    assert read["volume_mm3"] == pytest.approx(written["volume_mm3"], rel=1e-9)
