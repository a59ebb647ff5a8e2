"""Point-cloud files (PLY) as a dataset stores them: (N, 3) points in the scanner frame.

The world writes the scans with :func:`write_ply`; the researcher reads them with
:func:`read_ply`, which also takes a lab's files in millimetres. The format is read and written
with numpy alone (no open3d), so a process that only moves clouds through files does not load
open3d's 170 MB of native code: the vertex element of an ``ascii``, ``binary_little_endian`` or
``binary_big_endian`` PLY, any scalar property types, extra properties (colours, normals) and
elements after the vertices (faces) ignored. ``tests/test_ply.py`` checks the files against
open3d's own reader.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import DatasetError, OutOfRangeError

_UNITS = {"m": 1.0, "mm": 1e-3}
# PLY scalar type names (both spellings of the standard) -> numpy type codes without byte order.
_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip
_ORDER = {"binary_little_endian": "<", "binary_big_endian": ">", "ascii": "<"}
MAX_CLOUD_COORDINATE_M = 50.0  # no lab scanner sees farther: larger values are mm read as m
_MAX_HEADER_LINES = 10_000  # a real header is a few dozen lines; this bounds a corrupt file


def _as_points(points) -> np.ndarray:
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3 or not np.all(np.isfinite(pts)):
        raise OutOfRangeError(f"points must be a finite (N, 3) array [m], got shape {pts.shape}")
    return pts


def _unit(length_unit: str) -> float:
    if length_unit not in _UNITS:
        raise OutOfRangeError(f"length_unit = {length_unit!r} is not one of {', '.join(_UNITS)}")
    return _UNITS[length_unit]


def write_ply(path, points, length_unit: str = "m", binary: bool = True) -> Path:
    """Write (N, 3) points [m] as a PLY file in ``length_unit`` ('m' or 'mm').

    The binary default stores little-endian doubles exactly; ``binary=False`` writes text with
    17 significant digits, which also reads back exactly (and can be read by eye).
    """
    scale = _unit(length_unit)
    pts = _as_points(points) / scale
    if len(pts) == 0:
        raise DatasetError(f"could not write the point cloud file {path}: no points")
    fmt = "binary_little_endian" if binary else "ascii"
    header = (
        f"ply\nformat {fmt} 1.0\ncomment vtestbed, units {length_unit}\nelement vertex {len(pts)}\n"
        "property double x\nproperty double y\nproperty double z\nend_header\n"
    )
    path = Path(path)
    try:
        with open(path, "wb") as fh:
            fh.write(header.encode("ascii"))
            if binary:
                fh.write(np.ascontiguousarray(pts, dtype="<f8").tobytes())
            else:
                np.savetxt(fh, pts, fmt="%.17g")
    except OSError as exc:
        raise DatasetError(f"could not write the point cloud file {path}: {exc.strerror or exc}") from None
    return path


def read_ply(path, length_unit: str = "m") -> np.ndarray:
    """(N, 3) points [m] of a PLY file whose coordinates are in ``length_unit`` ('m' or 'mm')."""
    scale = _unit(length_unit)
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"point cloud file not found: {path}")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise DatasetError(f"could not read the point cloud file {path}: {exc.strerror or exc}") from None
    points = _vertices(raw, path) * scale
    if len(points) == 0:
        raise DatasetError(f"point cloud file {path} holds no points (not a PLY point cloud?)")
    return points


def _vertices(raw: bytes, path: Path) -> np.ndarray:
    """(N, 3) float64 x, y, z of the vertex element; (0, 3) for a file that is not a PLY at all."""
    empty = np.empty((0, 3))
    if not raw.startswith(b"ply") or raw[3:4] not in (b"\n", b"\r"):
        return empty
    fmt, elements, body = _header(raw, path)
    skip, vertex = 0, None
    for k, (name, count, props) in enumerate(elements):
        if name == "vertex":
            vertex, last = (count, props), k == len(elements) - 1
            break
        if fmt == "ascii":
            skip += count
        elif any(kind == "list" for _, kind in props):
            raise DatasetError(
                f"{path}: element {name!r} with list properties before the vertices is not supported"
            )
        else:
            skip += count * sum(np.dtype(kind).itemsize for _, kind in props)
    if vertex is None:
        return empty
    count, props = vertex
    names = [p for p, _ in props]
    if any(kind == "list" for _, kind in props):
        raise DatasetError(f"{path}: list properties in the vertex element are not supported")
    if not {"x", "y", "z"} <= set(names):
        raise DatasetError(f"{path}: the vertex element has no x, y, z properties (has {', '.join(names)})")
    if fmt == "ascii":
        values = _ascii_rows(raw[body:], skip, count, len(props), path, last)
        cols = [names.index(c) for c in "xyz"]
        return values[:, cols].astype(float)
    order = _ORDER[fmt]
    dtype = np.dtype([(p, order + kind) for p, kind in props])
    start = body + skip
    if len(raw) < start + count * dtype.itemsize:
        raise DatasetError(
            f"{path}: truncated: the header announces {count} vertices, the file holds "
            f"{max(0, len(raw) - start) // dtype.itemsize}"
        )
    extra = len(raw) - (start + count * dtype.itemsize)
    if last and extra >= dtype.itemsize:  # a whole vertex more (a trailing newline is a writer's habit)
        raise DatasetError(_beyond_count(path, count, f"{extra} bytes"))
    table = np.frombuffer(raw, dtype=dtype, count=count, offset=start)
    return np.stack([table[c].astype(float) for c in "xyz"], axis=1)


def _header(raw: bytes, path: Path):
    """(format, [(element, count, [(property, numpy kind or 'list')])], offset of the body)."""
    fmt, elements, offset = None, [], 0
    for _ in range(_MAX_HEADER_LINES):
        end = raw.find(b"\n", offset)
        if end < 0:
            break
        line = raw[offset:end].decode("ascii", "replace").strip()
        offset = end + 1
        words = line.split()
        if not words or words[0] in ("ply", "comment", "obj_info"):
            continue
        if words[0] == "end_header":
            if fmt is None:
                raise DatasetError(f"{path}: PLY header without a format line")
            return fmt, elements, offset
        if words[0] == "format" and len(words) >= 2 and words[1] in _ORDER:
            fmt = words[1]
        elif words[0] == "element" and len(words) == 3 and words[2].isdigit():
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements and len(words) == 3 and words[1] in _TYPES:
            elements[-1][2].append((words[2], _TYPES[words[1]]))
        elif words[0] == "property" and elements and len(words) == 5 and words[1] == "list":
            elements[-1][2].append((words[4], "list"))
        else:
            raise DatasetError(f"{path}: malformed PLY header line {line[:80]!r}")
    raise DatasetError(f"{path}: PLY header without end_header")


def _beyond_count(path: Path, count: int, what: str) -> str:
    return (f"{path}: {what} follow the {count} vertices the header announces, and no element after them: "
            "a vertex count too small, or a damaged file")  # fmt: skip


def _ascii_rows(body: bytes, skip: int, count: int, width: int, path: Path, last: bool) -> np.ndarray:
    parts = body.split(b"\n", skip + count)
    lines = parts[skip : skip + count]
    if len(lines) < count:
        raise DatasetError(f"{path}: the header announces {count} vertices, the file holds {len(lines)}")
    rest = parts[skip + count] if len(parts) > skip + count else b""
    if last and rest.strip():
        raise DatasetError(_beyond_count(path, count, f"{len(rest.strip().splitlines())} more lines"))
    try:  # numpy's C parser: a lab's ASCII scan of 100 k points reads in a fraction of a second
        values = np.loadtxt(lines, dtype=float, ndmin=2, encoding="ascii")  # every line exactly `width`
    except ValueError:
        raise DatasetError(f"{path}: a vertex line that is not {width} numbers") from None
    if values.shape != (count, width):
        raise DatasetError(
            f"{path}: the header announces {count} vertices of {width} values; the body differs"
        )
    return values
