"""PLY point-cloud files: round trips in m and mm, against the bytes and text an independent
reader sees (numpy, open3d's reader and writer), and the errors for missing, empty and malformed
input."""

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


def test_ascii_files_read_back_exactly(tmp_path):
    pts = _synthetic_points(50)
    path = write_ply(tmp_path / "a.ply", pts, binary=False)
    text = path.read_text().split("end_header\n")[1]
    body = np.loadtxt(text.splitlines())
    np.testing.assert_array_equal(body, pts)  # 17 significant digits: every double exactly
    np.testing.assert_array_equal(read_ply(path), pts)


def _open3d():
    from vtestbed._open3d import o3d

    return o3d


@pytest.mark.parametrize("binary", [True, False])
def test_open3d_reads_our_files_and_we_read_open3d_files(tmp_path, binary):
    """open3d (the reference PLY implementation the project used before) agrees both ways."""
    o3d = _open3d()
    pts = _synthetic_points(300)
    ours = write_ply(tmp_path / "ours.ply", pts, binary=binary)
    theirs = np.asarray(o3d.io.read_point_cloud(str(ours), format="ply").points)
    # open3d parses ASCII numbers with its own strtod: within 1 ulp of ours
    np.testing.assert_allclose(theirs, pts, rtol=3e-16 if not binary else 0, atol=0)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    cloud.colors = o3d.utility.Vector3dVector(np.random.default_rng(2).random((len(pts), 3)))
    cloud.normals = o3d.utility.Vector3dVector(np.tile([0.0, 0.0, 1.0], (len(pts), 1)))
    path = str(tmp_path / "theirs.ply")
    assert o3d.io.write_point_cloud(path, cloud, write_ascii=not binary)
    reference = np.asarray(o3d.io.read_point_cloud(path, format="ply").points)
    np.testing.assert_allclose(read_ply(path), reference, rtol=3e-16, atol=0)
    if binary:  # the doubles themselves
        np.testing.assert_array_equal(read_ply(path), pts)


def test_float32_big_endian_and_faces_read_as_open3d_reads_them(tmp_path):
    """A lab's scanner file: float32 coordinates, intensities, a face element after the vertices."""
    rng = np.random.default_rng(3)
    pts = rng.normal(0.0, 100.0, (40, 3)).astype(np.float32)
    for order, fmt in (("<", "binary_little_endian"), (">", "binary_big_endian")):
        table = np.zeros(
            40, dtype=[("i", order + "u1"), ("x", order + "f4"), ("y", order + "f4"), ("z", order + "f4")]
        )
        table["i"], table["x"], table["y"], table["z"] = 7, pts[:, 0], pts[:, 1], pts[:, 2]
        header = (
            f"ply\nformat {fmt} 1.0\nelement vertex 40\nproperty uchar intensity\nproperty float x\n"
            "property float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
        )
        face = np.array([3], dtype="u1").tobytes() + np.array([0, 1, 2], dtype=order + "i4").tobytes()
        path = tmp_path / f"{fmt}.ply"
        path.write_bytes(header.encode() + table.tobytes() + face)
        np.testing.assert_array_equal(read_ply(path, "mm"), pts.astype(float) * 1e-3)
        if order == "<":  # open3d reads little-endian files: the same doubles
            reference = np.asarray(_open3d().io.read_point_cloud(str(path), format="ply").points)
            np.testing.assert_array_equal(read_ply(path), reference)


def test_malformed_and_truncated_files_name_the_problem(tmp_path):
    pts = _synthetic_points(10)
    raw = write_ply(tmp_path / "a.ply", pts).read_bytes()
    (tmp_path / "cut.ply").write_bytes(raw[:-8])
    with pytest.raises(
        DatasetError, match=r"cut\.ply: truncated: the header announces 10 vertices, the file holds 9"
    ):
        read_ply(tmp_path / "cut.ply")
    (tmp_path / "noxyz.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 1\nproperty float a\nend_header\n1\n"
    )
    with pytest.raises(DatasetError, match="has no x, y, z properties"):
        read_ply(tmp_path / "noxyz.ply")
    (tmp_path / "bad.ply").write_text("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nbogus\n")
    with pytest.raises(DatasetError, match="malformed PLY header line 'bogus'"):
        read_ply(tmp_path / "bad.ply")
    (tmp_path / "text.ply").write_text("ply\nformat ascii 1.0\nelement vertex 2\n" + "".join(
        f"property double {c}\n" for c in "xyz") + "end_header\n1 2 3\n4 five 6\n")  # fmt: skip
    with pytest.raises(DatasetError, match="a vertex line that is not 3 numbers"):
        read_ply(tmp_path / "text.ply")
    with pytest.raises(DatasetError, match="could not write the point cloud file"):
        write_ply(tmp_path / "no" / "such" / "dir.ply", pts)


def test_points_beyond_the_header_count_are_refused_not_dropped(tmp_path):
    """A header count below the data would silently drop the last points; bytes after the last
    element are a damaged file. Both are refused; a face element after the vertices is not."""
    pts = _synthetic_points(10)
    raw = write_ply(tmp_path / "a.ply", pts).read_bytes()
    (tmp_path / "few.ply").write_bytes(raw.replace(b"element vertex 10", b"element vertex 9", 1))
    with pytest.raises(DatasetError, match=r"few\.ply: 24 bytes follow the 9 vertices the header announces"):
        read_ply(tmp_path / "few.ply")
    (tmp_path / "tail.ply").write_bytes(raw + b"junk" * 6)  # a whole vertex's worth
    with pytest.raises(DatasetError, match=r"tail\.ply: 24 bytes follow the 10 vertices"):
        read_ply(tmp_path / "tail.ply")
    (tmp_path / "newline.ply").write_bytes(raw + b"\n")  # a writer's trailing newline: read as before
    np.testing.assert_array_equal(read_ply(tmp_path / "newline.ply"), pts)
    text = write_ply(tmp_path / "t.ply", pts, binary=False).read_text()
    (tmp_path / "few.txt.ply").write_text(text.replace("element vertex 10", "element vertex 8", 1))
    with pytest.raises(DatasetError, match="2 more lines follow the 8 vertices"):
        read_ply(tmp_path / "few.txt.ply")
    head, body = text.split("end_header\n")
    (tmp_path / "wide.ply").write_text(head + "end_header\n" + body.replace("\n", " 7\n", 1))
    with pytest.raises(DatasetError, match="a vertex line that is not 3 numbers"):
        read_ply(tmp_path / "wide.ply")
    faces = text.replace("end_header", "element face 1\nproperty list uchar int vertex_indices\nend_header")
    (tmp_path / "faces.ply").write_text(faces + "3 0 1 2\n")
    np.testing.assert_allclose(read_ply(tmp_path / "faces.ply"), pts, rtol=1e-5)  # ASCII: 6 digits


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
