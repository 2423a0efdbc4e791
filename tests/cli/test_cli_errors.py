"""Bad input through the real ``thrsim`` command: exit 2, one line on stderr naming problem and file,
no traceback, nothing written."""

from __future__ import annotations

import re

import pytest

GOOD = """*NODE
1, 0.0, 0.0, 0.0
2, 1.0, 0.0, 0.0
3, 0.0, 1.0, 0.0
4, 0.0, 0.0, 1.0
5, 1.0, 1.0, 1.0
*ELEMENT, TYPE=C3D4
1, 1, 2, 3, 4
2, 2, 3, 4, 5
"""

HEX = """*NODE
1, 0, 0, 0
2, 1, 0, 0
3, 1, 1, 0
4, 0, 1, 0
5, 0, 0, 1
6, 1, 0, 1
7, 1, 1, 1
8, 0, 1, 1
*ELEMENT, TYPE=C3D8
1, 1, 2, 3, 4, 5, 6, 7, 8
"""

BAD_FILES = {
    "missing": ("missing.inp", None, r"no such file"),
    "garbled": ("garbled.inp", b"\x00\x01garbage\xff\n*ELEMENT, TYPE=\n1, x, y\n", r"cannot read|no tetrahedral"),
    "empty": ("empty.inp", b"", r"cannot read|no tetrahedral"),
    "garbled_vtu": ("garbled.vtu", b"<VTKFile><<<", r"cannot read"),
    "garbled_msh": ("garbled.msh", b"$MeshFormat\nnonsense\n", r"cannot read"),
    "garbled_h5": ("garbled.h5", b"not hdf5", r"cannot read"),
    "hexahedral": ("hex.inp", HEX, r"no tetrahedral elements"),
    "inverted": ("inverted.inp", GOOD.replace("2, 2, 3, 4, 5", "2, 2, 4, 3, 5"), r"inverted"),
    "zero_volume": ("flat.inp", GOOD.replace("5, 1.0, 1.0, 1.0", "5, 0.5, 0.5, 0.0"), r"zero-volume"),
    "repeated_node": ("repeat.inp", GOOD.replace("2, 2, 3, 4, 5", "2, 2, 3, 4, 4"), r"zero-volume"),
    "nan": ("nan.inp", GOOD.replace("5, 1.0, 1.0, 1.0", "5, nan, 1.0, 1.0"), r"NaN"),
}


def assert_one_line_error(result, *needles: str) -> str:
    assert result.returncode == 2, (result.returncode, result.stdout, result.stderr)
    assert "Traceback" not in result.stderr + result.stdout
    lines = result.stderr.splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("thrsim: error: ")
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    assert result.stdout == ""
    return lines[0]


def check_bad_file(run, folder, case: str, out_suffix: str) -> None:
    name, content, problem = BAD_FILES[case]
    source = folder / name
    if isinstance(content, bytes):
        source.write_bytes(content)
    elif content is not None:
        source.write_text(content)
    before = sorted(p.name for p in folder.iterdir())
    line = assert_one_line_error(run("mesh", "--from", name, "--out", f"result{out_suffix}", "--json", cwd=folder), name)
    assert re.search(problem, line), line
    # neither the output nor a temporary of it was written
    assert sorted(p.name for p in folder.iterdir()) == before


@pytest.mark.parametrize("case", sorted(BAD_FILES))
@pytest.mark.parametrize("out_suffix", [".vtu", ".msh", ".inp", ".h5"])
def test_bad_mesh_file(thrsim_inprocess, tmp_path, case, out_suffix):
    check_bad_file(thrsim_inprocess, tmp_path, case, out_suffix)


@pytest.mark.parametrize("case", ["missing", "hexahedral", "nan"])
def test_bad_mesh_file_through_the_console_script(thrsim, tmp_path, case):
    check_bad_file(thrsim, tmp_path, case, ".vtu")


def test_good_file_is_accepted(thrsim_inprocess, tmp_path):
    (tmp_path / "good.inp").write_text(GOOD)
    result = thrsim_inprocess("mesh", "--from", "good.inp", "--out", "good.vtu", "--json", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["good.inp", "good.vtu"]


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--element-size", "-1"], "element_size_mm"),
        (["--element-size", "0"], "element_size_mm"),
        (["--half-angle", "95"], "half_angle_deg"),
        (["--thickness", "-2"], "thickness_mm"),
        (["--side", "up"], "--side"),
        (["--units", "km"], "--units"),
        (["--out", "mesh.stl"], "mesh.stl"),
        (["--out", "nowhere/mesh.vtu"], "nowhere"),
        (["--from", "x.inp", "--element-size", "1"], "--element-size"),
    ],
)
def test_bad_options(thrsim_inprocess, tmp_path, args, needle):
    assert_one_line_error(thrsim_inprocess("mesh", *args, "--json", cwd=tmp_path), needle)
    assert list(tmp_path.iterdir()) == []


def test_bad_option_through_the_console_script(thrsim, tmp_path):
    line = assert_one_line_error(thrsim("mesh", "--element-size", "-1", "--json", cwd=tmp_path), "element_size_mm")
    assert "invalid configuration" in line


def test_an_os_error_is_one_line_and_exit_2(thrsim_inprocess, tmp_path, monkeypatch):
    """Whatever the system refuses on a path (no space, no permission) reaches the user as the documented line."""
    import errno

    import thrsim.cli.mesh_cmd as mesh_cmd

    def full_disk(mesh, path, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(mesh_cmd, "write_mesh", full_disk)
    line = assert_one_line_error(thrsim_inprocess("mesh", "--element-size", "1.2", "--out", "m.vtu", cwd=tmp_path), "m.vtu")
    assert line == "thrsim: error: m.vtu: No space left on device"
