"""PLY point-cloud files: round trips in m and mm, against the bytes and text an independent
reader sees, and the errors for missing, empty and malformed input."""

from __future__ import annotations

import numpy as np
import pytest

from vtestbed.errors import DatasetError, OutOfRangeError
from vtestbed.ply import read_ply, write_ply
from vtestbed.world.scan_noise import ScanNoise


def test_ply_round_trip(scene, tmp_path):
    _, _, _, hits = scene
    pts = ScanNoise().apply(hits, np.random.default_rng(0))
    assert np.array_equal(read_ply(write_ply(tmp_path / "a.ply", pts)), pts)
    np.testing.assert_allclose(
        read_ply(write_ply(tmp_path / "b.ply", pts, "mm"), "mm"), pts, rtol=0, atol=1e-15
    )
    raw = read_ply(tmp_path / "b.ply")  # the same file read as metres is 1000x larger
    np.testing.assert_allclose(raw, pts * 1e3, rtol=1e-15)
    with pytest.raises(DatasetError, match="not found"):
        read_ply(tmp_path / "missing.ply")
    with pytest.raises(OutOfRangeError, match="length_unit = 'inch'"):
        read_ply(tmp_path / "a.ply", "inch")


def _synthetic_points(count=500):
    """Points as a scan delivers them: around 0.6 m from the scanner, sub-micrometre detail."""
    rng = np.random.default_rng(1)
    return rng.normal(0.0, 0.05, (count, 3)) + [0.0, 0.0, 0.6]


def _binary_body(path) -> tuple[str, np.ndarray]:
    """Header text and the doubles after it, read with numpy alone (little-endian x, y, z)."""
    raw = path.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    return raw[:end].decode("ascii"), np.frombuffer(raw[end:], dtype="<f8").reshape(-1, 3)


def test_binary_file_holds_the_doubles_in_the_chosen_unit(tmp_path):
    pts = _synthetic_points()
    header, body = _binary_body(write_ply(tmp_path / "m.ply", pts))
    assert "format binary_little_endian 1.0" in header and f"element vertex {len(pts)}" in header
    assert header.count("property double") == 3
    assert np.array_equal(body, pts)  # metres, bit-exact
    _, body_mm = _binary_body(write_ply(tmp_path / "mm.ply", pts, "mm"))
    np.testing.assert_allclose(body_mm, pts * 1000.0, rtol=5e-16, atol=0)  # x / 1e-3: within 2 ulp
    assert np.array_equal(read_ply(tmp_path / "m.ply"), pts)
    np.testing.assert_allclose(read_ply(tmp_path / "mm.ply", "mm"), pts, rtol=5e-16, atol=0)


def test_a_lab_file_in_mm_reads_as_metres(tmp_path):
    """A PLY written by another tool (ASCII, millimetres) reads as the same points in metres."""
    pts_mm = np.array([[600.125, -12.5, 3.0], [0.001, 250.0, -1.75]])
    lines = ["ply", "format ascii 1.0", "element vertex 2"]
    lines += [f"property double {c}" for c in "xyz"] + ["end_header"]
    lines += [" ".join(repr(float(v)) for v in row) for row in pts_mm]
    path = tmp_path / "lab.ply"
    path.write_text("\n".join(lines) + "\n")
    np.testing.assert_allclose(read_ply(path, "mm"), pts_mm / 1000.0, rtol=1e-15, atol=0)
    np.testing.assert_array_equal(read_ply(path), pts_mm)


def test_ascii_files_hold_six_significant_digits(tmp_path):
    pts = _synthetic_points(50)
    path = write_ply(tmp_path / "a.ply", pts, binary=False)
    text = path.read_text().split("end_header\n")[1]
    body = np.loadtxt(text.splitlines())
    np.testing.assert_allclose(body, pts, rtol=5e-6, atol=0)  # open3d writes %g
    np.testing.assert_array_equal(read_ply(path), body)


def test_bad_points_units_and_files_are_refused(tmp_path):
    for bad, shape in (
        (np.zeros((4, 2)), r"\(4, 2\)"),
        (np.full((2, 3), np.nan), r"\(2, 3\)"),
        (np.zeros(3), r"\(3,\)"),
    ):
        with pytest.raises(
            OutOfRangeError, match=rf"points must be a finite \(N, 3\) array \[m\], got shape {shape}"
        ):
            write_ply(tmp_path / "x.ply", bad)
    with pytest.raises(OutOfRangeError, match="length_unit = 'cm' is not one of m, mm"):
        write_ply(tmp_path / "x.ply", np.zeros((1, 3)), "cm")
    assert not (tmp_path / "x.ply").exists()
    with pytest.raises(DatasetError, match=r"point cloud file not found: .*missing\.ply"):
        read_ply(tmp_path / "missing.ply")
    (tmp_path / "text.ply").write_text("not a point cloud\n")
    with pytest.raises(DatasetError, match=r"text\.ply holds no points \(not a PLY point cloud\?\)"):
        read_ply(tmp_path / "text.ply")
