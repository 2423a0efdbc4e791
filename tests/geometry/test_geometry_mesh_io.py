"""Mesh I/O round trips through every writable format, units, node sets, atomic writes."""

from __future__ import annotations

import stat

import h5py
import meshio
import numpy as np
import pytest
from geometry_helpers import CUBE_NODES, CUBE_TETS, orient

from thrsim.errors import ThrsimInputError
from thrsim.geometry.mesh import TetMesh
from thrsim.geometry.mesh_io import WRITABLE_SUFFIXES, read_mesh, write_mesh


@pytest.fixture
def cube_mesh() -> TetMesh:
    """A 2 cm cube in metres with two node sets and fixed nodes."""
    nodes = CUBE_NODES * 0.02 - 0.01
    return TetMesh(
        nodes=nodes,
        tets=orient(nodes, CUBE_TETS),
        node_sets={"bottom": [0, 1, 2, 3], "top": [4, 5, 6, 7]},
        fixed_nodes=[0, 1, 2, 3],
    )


def assert_same_mesh(a: TetMesh, b: TetMesh, atol: float = 1e-12) -> None:
    assert (a.n_nodes, a.n_tets) == (b.n_nodes, b.n_tets)
    np.testing.assert_allclose(a.nodes, b.nodes, rtol=0, atol=atol)
    np.testing.assert_array_equal(a.tets, b.tets)
    assert set(a.node_sets) == set(b.node_sets)
    for name in a.node_sets:
        np.testing.assert_array_equal(a.node_sets[name], b.node_sets[name])
    np.testing.assert_array_equal(a.fixed_nodes, b.fixed_nodes)


@pytest.mark.parametrize("suffix", WRITABLE_SUFFIXES)
def test_round_trip_small_mesh(tmp_path, cube_mesh, suffix):
    path = write_mesh(cube_mesh, tmp_path / f"cube{suffix}")
    assert path.exists()
    assert_same_mesh(cube_mesh, read_mesh(path))
    assert [p.name for p in tmp_path.iterdir()] == [f"cube{suffix}"]  # no temporary left behind


@pytest.mark.parametrize("suffix", WRITABLE_SUFFIXES)
def test_round_trip_bone_patch(tmp_path, coarse_patch, suffix):
    path = write_mesh(coarse_patch, tmp_path / f"patch{suffix}")
    again = read_mesh(path)
    assert_same_mesh(coarse_patch, again, atol=1e-12)
    assert again.validate().valid
    np.testing.assert_allclose(again.volumes, coarse_patch.volumes, rtol=1e-9)


@pytest.mark.parametrize("suffix", [".vtu", ".msh", ".inp"])
def test_exchange_formats_are_in_millimetres_unless_told(tmp_path, cube_mesh, suffix):
    mm = write_mesh(cube_mesh, tmp_path / f"mm{suffix}")
    m = write_mesh(cube_mesh, tmp_path / f"m{suffix}", units="m")
    np.testing.assert_allclose(meshio.read(mm).points, cube_mesh.nodes * 1e3)
    np.testing.assert_allclose(meshio.read(m).points, cube_mesh.nodes)
    assert_same_mesh(cube_mesh, read_mesh(m, units="m"))
    # a millimetre file read as metres is a thousand times too big
    np.testing.assert_allclose(read_mesh(mm, units="m").nodes, cube_mesh.nodes * 1e3)


def test_h5_is_always_si(tmp_path, cube_mesh):
    path = write_mesh(cube_mesh, tmp_path / "cube.h5", units="mm", metadata={"source": "test"})
    with h5py.File(path) as f:
        assert f.attrs["format"] == "thrsim-mesh" and f.attrs["units"] == "m"
        np.testing.assert_array_equal(f["mesh/nodes"][()], cube_mesh.nodes)
        assert f["mesh/tets"].dtype == np.int32 and f["mesh/fixed_nodes"].dtype == np.int32
        assert "numpy" in f.attrs["versions"]
    assert_same_mesh(cube_mesh, read_mesh(path, units="mm"))


def test_written_files_are_not_private(tmp_path, cube_mesh):
    path = write_mesh(cube_mesh, tmp_path / "cube.vtu")
    assert stat.S_IMODE(path.stat().st_mode) & 0o044  # readable by group/others under the usual umask


def test_abaqus_fixed_set_name_is_case_insensitive(tmp_path):
    text = (
        "*NODE\n1, 0, 0, 0\n2, 1, 0, 0\n3, 0, 1, 0\n4, 0, 0, 1\n"
        "*ELEMENT, TYPE=C3D4, ELSET=BONE\n1, 1, 2, 3, 4\n"
        "*NSET, NSET=FIXED\n1, 2, 3\n*NSET, NSET=Tip\n4\n"
    )
    path = tmp_path / "hand.inp"
    path.write_text(text)
    mesh = read_mesh(path)
    np.testing.assert_array_equal(mesh.fixed_nodes, [0, 1, 2])
    assert set(mesh.node_sets) == {"Tip"}
    out = write_mesh(mesh, tmp_path / "again.inp")
    assert out.read_text().upper().count("NSET=FIXED") == 1
    assert_same_mesh(mesh, read_mesh(out))


def test_quadratic_tets_keep_their_corners(tmp_path):
    nodes = CUBE_NODES[[0, 1, 2, 4]]
    mids = np.array([(nodes[i] + nodes[j]) / 2 for i, j in [(0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3)]])
    path = tmp_path / "quadratic.vtu"
    meshio.write(path, meshio.Mesh(np.vstack([nodes, mids]), [("tetra10", np.arange(10)[None])]))
    mesh = read_mesh(path)
    assert mesh.n_tets == 1
    np.testing.assert_array_equal(mesh.tets, [[0, 1, 2, 3]])


def test_unsupported_output_and_missing_folder(tmp_path, cube_mesh):
    with pytest.raises(ThrsimInputError, match="unsupported output format"):
        write_mesh(cube_mesh, tmp_path / "cube.stl")
    with pytest.raises(ThrsimInputError, match="does not exist"):
        write_mesh(cube_mesh, tmp_path / "nowhere" / "cube.vtu")
    assert list(tmp_path.iterdir()) == []


def test_failed_write_leaves_nothing(tmp_path, cube_mesh, monkeypatch):
    import thrsim.geometry.mesh_io as mesh_io

    def explode(*args, **kwargs):
        raise RuntimeError("disk full")

    monkeypatch.setattr(mesh_io, "_write_meshio", explode)
    (tmp_path / "keep.vtu").write_text("old")
    with pytest.raises(RuntimeError):
        write_mesh(cube_mesh, tmp_path / "keep.vtu")
    assert [p.name for p in tmp_path.iterdir()] == ["keep.vtu"]
    assert (tmp_path / "keep.vtu").read_text() == "old"


@pytest.mark.parametrize(
    ("name", "content", "problem"),
    [
        ("missing.inp", None, "no such file"),
        (
            "hex.inp",
            "*NODE\n1,0,0,0\n2,1,0,0\n3,1,1,0\n4,0,1,0\n5,0,0,1\n6,1,0,1\n7,1,1,1\n8,0,1,1\n*ELEMENT, TYPE=C3D8\n1,1,2,3,4,5,6,7,8\n",
            "no tetrahedral elements",
        ),
        ("empty.h5", b"", "cannot read HDF5"),
        ("garbage.vtu", "<VTKFile><<<", "cannot read mesh"),
    ],
)
def test_read_refuses_bad_files(tmp_path, name, content, problem):
    path = tmp_path / name
    if isinstance(content, bytes):
        path.write_bytes(content)
    elif content is not None:
        path.write_text(content)
    with pytest.raises(ThrsimInputError, match=problem) as error:
        read_mesh(path)
    assert str(path) in str(error.value)


def test_one_mesh_group_reader_for_mesh_files_and_case_files(tmp_path):
    """Mesh files and ground-truth case files share the /mesh group; its reader lives beside its writer."""
    from thrsim.config import ReamingCaseConfig
    from thrsim.data.case_file import read_case
    from thrsim.data.synthetic import block_mesh, synthetic_run_case
    from thrsim.geometry.mesh_io import read_mesh_group, write_mesh_group

    mesh = block_mesh(n=2)
    with h5py.File(tmp_path / "m.h5", "w") as f:
        write_mesh_group(f.create_group("mesh"), mesh)
    with h5py.File(tmp_path / "m.h5", "r") as f:
        back = read_mesh_group(f["mesh"])
    assert np.array_equal(back.nodes, mesh.nodes) and np.array_equal(back.tets, mesh.tets)
    assert np.array_equal(back.fixed_nodes, mesh.fixed_nodes) and set(back.node_sets) == set(mesh.node_sets)
    synthetic_run_case(ReamingCaseConfig(inclination_deg=0, anteversion_deg=0, frames=2), tmp_path / "c.h5")
    with h5py.File(tmp_path / "c.h5", "r") as f:
        from_group = read_mesh_group(f["mesh"])
    assert np.array_equal(read_case(tmp_path / "c.h5").mesh.tets, from_group.tets)
    assert np.array_equal(read_mesh(tmp_path / "c.h5").nodes, from_group.nodes)
