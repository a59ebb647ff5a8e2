"""Mesh targets: a user's scanned artefact (STL, OBJ, PLY) instead of the plain box (trimesh).

A scenario's ``[target]`` table names a mesh file; :func:`load_mesh_target` reads it with trimesh,
checks it and computes its mass properties (docs/targets.md):

- readable, one watertight, consistently wound triangle mesh of positive volume;
- its size, in the declared ``units`` (``"mm"`` or ``"m"``), between :data:`SIZE_RANGE_M` along
  every axis (a file in mm declared as m is 1000 times too large, and refused);
- three mutually perpendicular planar faces to fit: the mesh's outermost faces whose outward
  normals are the mesh's own +x, +y and +z axes. They define the block frame B: its axes are the
  mesh's axes and its origin the corner where the three face planes meet (on a chamfered block
  that corner is virtual: the chamfers cut it off, exactly the paper's O_i). Each face must be
  flat, span at least :data:`MIN_FACE_FRACTION` of the block's size along both in-plane axes and
  reach within :data:`MAX_CORNER_GAP_FRACTION` of the block's size of the corner;
- mass from a density or a given mass; centre of mass and inertia about it, in B (trimesh's
  exact integrals over the closed surface).

The hooks of the plain box (centres of the -x and -y faces, middle of the -x/-y edge) are moved
to the nearest point of the mesh surface, so a wire never hangs in the air where a chamfer cut the
edge away. :func:`chamfered_block` generates the shipped example (``models/targets/``).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import ScenarioError
from .schema import Fields

UNITS = {"m": 1.0, "mm": 1e-3}  # metres per unit
SUFFIXES = (".stl", ".obj", ".ply")
SIZE_RANGE_M = (0.02, 0.3)  # every bounding-box extent; the same range as [lab.block] edge_m
DENSITY_RANGE = (100.0, 25000.0)  # kg/m^3, as [lab.block] density_kg_m3
MASS_RANGE_KG = (1e-3, 50.0)
MIN_FACE_FRACTION = 0.5  # a fitted face spans this fraction of the size (the researcher's extent check)
MAX_CORNER_GAP_FRACTION = 0.25  # a fitted face reaches this close to the corner, as a fraction of the size
FACE_ANGLE_TOL_RAD = np.radians(0.05)  # a fitted face's triangles: normal within this of the axis
FLATNESS_TOL_M = 1e-6  # ... and vertices within this of the plane (STL stores float32)
MODELS_TARGETS = Path(__file__).resolve().parent.parent / "models" / "targets"
CHAMFERED_BLOCK = MODELS_TARGETS / "chamfered_block_80mm.stl"
_VALID_FILE = "one closed triangle surface of at least 4 triangles in an STL, OBJ or PLY file"


class TargetError(ScenarioError):
    """A mesh target that cannot be used: unreadable, not closed, implausible size, no corner to fit."""


class _TargetFields(Fields):
    """:class:`Fields` whose errors are :class:`TargetError`."""

    def error(self, field_name: str, message: str) -> TargetError:
        return TargetError(super().error(field_name, message).args[0])


@dataclass(frozen=True, eq=False)
class MeshTarget:
    """A checked mesh target in the block frame B, SI units.

    Attributes
    ----------
    path, sha256, units : str
        The file, its content hash and the unit it was declared in.
    vertices : (V, 3) array
        Vertices [m] in B (origin: the corner where the three fitted faces meet).
    faces : (F, 3) int array
        Triangles, outward (counter-clockwise) winding.
    extents : (3,) array
        Bounding-box size [m] along B's axes; the mesh occupies [-extents, 0] in B.
    volume, mass, density : float
        [m^3], [kg], [kg/m^3].
    com : (3,) array
        Centre of mass [m] in B.
    inertia : (3, 3) array
        Inertia tensor [kg*m^2] about the centre of mass, B's axes.
    face_areas : (3,) array
        Areas [m^2] of the flat faces +x, +y, +z.
    face_margin : float
        Largest gap [m] between a fitted face's flat region and the bounding box's edges (the
        chamfer width; 0 for a sharp box): points closer than this to an edge may lie on a chamfer.
    hooks : dict
        Hook points [m] in B on the mesh surface; ``hook_shift`` [m] how far each moved from the box's.
    """

    path: str
    sha256: str
    units: str
    vertices: np.ndarray
    faces: np.ndarray
    extents: np.ndarray
    volume: float
    mass: float
    density: float
    com: np.ndarray
    inertia: np.ndarray
    face_areas: np.ndarray
    face_margin: float
    hooks: dict
    hook_shift: dict

    @property
    def edge(self) -> float:
        """The largest extent [m]: the block's bounding cube [-edge, 0]^3 in B holds the mesh."""
        return float(self.extents.max())

    def setup_json(self) -> dict:
        """What the researcher needs to know about the target (the dataset's setup.json)."""
        return {
            "kind": "mesh",
            "file": Path(self.path).name,
            "sha256": self.sha256,
            "extents_m": self.extents.tolist(),
            "face_margin_m": self.face_margin,
            "mass_kg": self.mass,
        }


def _read(path: Path, f: Fields, field: str):
    import trimesh  # here: the CLI and the plain box never pay for it

    if path.suffix.lower() not in SUFFIXES:
        raise f.error(field, f"{path}: unsupported mesh format {path.suffix!r}; valid: {', '.join(SUFFIXES)}")
    try:
        data = path.read_bytes()
        mesh = trimesh.load_mesh(path, process=True)
    except Exception as exc:  # trimesh raises many kinds on a bad file: all mean "unreadable"
        raise f.error(
            field, f"{path}: cannot read the mesh ({type(exc).__name__}: {exc}); valid: {_VALID_FILE}"
        ) from None
    if isinstance(mesh, trimesh.Scene):
        mesh = mesh.to_geometry() if mesh.geometry else None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) < 4:
        raise f.error(field, f"{path}: cannot read the mesh (no triangles in it); valid: {_VALID_FILE}")
    return mesh, hashlib.sha256(data).hexdigest()


def _fitted_face(mesh, k: int, size: float, f: Fields, field: str, path: Path) -> tuple[float, float, float]:
    """The flat face with outward normal +axis k: its area [m^2], its gap to the corner and its
    margin to the bounding box [m] (mesh in B: bounding box [-extents, 0])."""
    axis = "xyz"[k]
    near = mesh.face_normals[:, k] > np.cos(FACE_ANGLE_TOL_RAD)
    tri = mesh.vertices[mesh.faces[near]]  # (n, 3, 3)
    on_plane = np.all(np.abs(tri[:, :, k]) <= FLATNESS_TOL_M, axis=1)
    tri, area = tri[on_plane], mesh.area_faces[near][on_plane]
    want = (
        f"valid: three mutually perpendicular planar faces whose outward normals are the mesh's +x, +y "
        f"and +z axes, meeting at a corner, each spanning at least {MIN_FACE_FRACTION:g} of the block's "
        f"size ({MIN_FACE_FRACTION * size * 1e3:.1f} mm) and reaching within "
        f"{MAX_CORNER_GAP_FRACTION * size * 1e3:.1f} mm of the corner (rotate the mesh so that they do)"
    )
    if len(tri) == 0:
        raise f.error(field, f"{path}: no planar face with outward normal +{axis} on the mesh's outermost +{axis} "
                      f"plane; {want}")  # fmt: skip
    others = [j for j in range(3) if j != k]
    lo, hi = tri.reshape(-1, 3).min(axis=0), tri.reshape(-1, 3).max(axis=0)
    span = min(hi[j] - lo[j] for j in others)
    gap = max(-hi[j] for j in others)
    if span < MIN_FACE_FRACTION * size or gap > MAX_CORNER_GAP_FRACTION * size:
        raise f.error(field, f"{path}: the planar +{axis} face spans {span * 1e3:.1f} mm and ends "
                      f"{gap * 1e3:.1f} mm from the corner; {want}")  # fmt: skip
    extents = -mesh.bounds[0]
    margin = max(max(-hi[j], lo[j] + extents[j]) for j in others)
    return float(area.sum()), float(gap), float(margin)


def load_mesh_target(
    path: str | Path,
    units: str = "mm",
    density: float | None = None,
    mass: float | None = None,
    fields: Fields | None = None,
    field: str = "target.mesh",
) -> MeshTarget:
    """Read, check and measure a mesh target (module docstring; docs/targets.md).

    Parameters
    ----------
    path : str or Path
        STL, OBJ or PLY file.
    units : {"mm", "m"}
        The unit of the file's coordinates.
    density, mass : float, optional
        Density [kg/m^3] or mass [kg]; at most one (neither: aluminium, 2700 kg/m^3).
    fields : Fields, optional
        Binds the scenario file that errors name; ``field`` is the key they name.

    Raises
    ------
    TargetError
        Naming the file, the field and the valid range: unreadable, not watertight, a size
        implausible for ``units``, no three perpendicular planar faces at a corner.
    """
    f, path = _TargetFields((fields or Fields()).source), Path(path)
    if units not in UNITS:
        raise f.error(field.replace("mesh", "units"), f"{path}: = {units!r}; valid: {', '.join(UNITS)}")
    if density is not None and mass is not None:
        raise f.error(field.replace("mesh", "mass_kg"), "give density_kg_m3 or mass_kg, not both")
    if not path.is_file():
        raise f.error(field, f"{path}: no such file")
    mesh, sha = _read(path, f, field)
    if not (mesh.is_watertight and mesh.is_winding_consistent):
        open_edges = int(
            np.sum(np.bincount(mesh.edges_unique_inverse, minlength=len(mesh.edges_unique)) != 2)
        )
        raise f.error(field, f"{path}: the mesh is not watertight ({open_edges} edges not shared by exactly two "
                      "triangles, or inconsistent winding); valid: one closed surface (repair it, e.g. in "
                      "MeshLab or with trimesh.repair)")  # fmt: skip
    scale = UNITS[units]
    extents_units = mesh.extents
    low, high = (v / scale for v in SIZE_RANGE_M)
    if not np.all((extents_units >= low) & (extents_units <= high)):
        raise f.error(field.replace("mesh", "units"), f"{path}: bounding box {np.round(extents_units, 4).tolist()} "
                      f"{units} is implausible for a target block; valid: every extent in [{low:g}, {high:g}] "
                      f"{units} ({SIZE_RANGE_M[0]:g}-{SIZE_RANGE_M[1]:g} m; is the file in "
                      f"{'m' if units == 'mm' else 'mm'}?)")  # fmt: skip
    mesh.apply_scale(scale)
    if mesh.volume < 0:
        mesh.invert()  # closed but inside out: the winding is consistent, only reversed
    corner = mesh.bounds[1].copy()
    mesh.apply_translation(-corner)
    size = float(mesh.extents.max())
    faces = [_fitted_face(mesh, k, size, f, field, path) for k in range(3)]
    volume = float(mesh.volume)
    if mass is not None:
        mass = f.number(mass, field.replace("mesh", "mass_kg"), *MASS_RANGE_KG)
        density = mass / volume
    density = f.number(2700.0 if density is None else density, field.replace("mesh", "density_kg_m3"),
                       *DENSITY_RANGE)  # fmt: skip
    mesh.density = density
    hooks, shift = _hooks(mesh)
    return MeshTarget(
        path=str(path), sha256=sha, units=units,
        vertices=np.array(mesh.vertices, dtype=float), faces=np.array(mesh.faces, dtype=np.int64),
        extents=np.array(mesh.extents, dtype=float), volume=volume, mass=density * volume, density=density,
        com=np.array(mesh.center_mass, dtype=float), inertia=np.array(mesh.moment_inertia, dtype=float),
        face_areas=np.array([a for a, _, _ in faces]), face_margin=max(m for _, _, m in faces),
        hooks=hooks, hook_shift=shift,
    )  # fmt: skip


def box_hooks(extents) -> dict[str, tuple[float, float, float]]:
    """The plain box's hook points [m] in B for a block of ``extents`` (3,): the centres of the -x
    and -y faces and the middle of the -x/-y edge (:attr:`vtestbed.lab.BlockSpec.hooks`)."""
    ex, ey, ez = (-float(v) for v in extents)
    return {"hook_x": (ex, ey / 2, ez / 2), "hook_y": (ex / 2, ey, ez / 2), "hook_edge": (ex, ey, ez / 2)}


def _hooks(mesh) -> tuple[dict, dict]:
    """The box's hooks moved to the nearest point of the mesh surface, and how far each moved [m]."""
    import trimesh

    hooks, shift = {}, {}
    for name, point in box_hooks(mesh.extents).items():  # every triangle: no spatial index (rtree) needed
        candidates = trimesh.triangles.closest_point(mesh.triangles, np.tile(point, (len(mesh.faces), 1)))
        distance = np.linalg.norm(candidates - point, axis=1)
        best = int(np.argmin(distance))
        hooks[name], shift[name] = tuple(float(v) for v in candidates[best]), float(distance[best])
    return hooks, shift


def chamfered_block(edge_m: float = 0.08, chamfer_m: float = 0.005, corner_at_origin: bool = False):
    """A cube of ``edge_m`` with every edge chamfered at 45 deg by ``chamfer_m`` (a trimesh.Trimesh).

    The cube occupies [0, edge]^3 (a CAD export's frame) or, with ``corner_at_origin``, [-edge, 0]^3.
    Each chamfer runs the whole edge, as a chamfer mill cuts it: the block is the cube cut by the
    12 half-spaces ``x_i + x_j <= 2 edge - chamfer`` (and the like at the other edges), so three
    chamfers meet in a point at each corner. Closed form: volume ``e^3 - 6 c^2 e + 6 c^3``.
    """
    import trimesh

    e, c = float(edge_m), float(chamfer_m)
    if not 0 <= c < e / 2:
        raise ValueError(f"chamfer_m = {c:g} must lie in [0, edge_m / 2) = [0, {e / 2:g})")
    points = []
    for k in range(3):  # the four corners of each face's flat square
        for side in (0.0, e):
            for a in (c, e - c):
                for b in (c, e - c):
                    p = np.empty(3)
                    p[k], p[(k + 1) % 3], p[(k + 2) % 3] = side, a, b
                    points.append(p)
    for x in (c / 2, e - c / 2):  # the point where three chamfers meet at each corner
        for y in (c / 2, e - c / 2):
            for z in (c / 2, e - c / 2):
                points.append((x, y, z))
    points = np.unique(np.round(np.array(points), 15), axis=0)
    mesh = trimesh.convex.convex_hull(points)
    if corner_at_origin:
        mesh.apply_translation([-e, -e, -e])
    return mesh


def write_chamfered_block(
    path: Path = CHAMFERED_BLOCK, edge_m: float = 0.08, chamfer_m: float = 0.005
) -> Path:
    """Write the shipped example: the default block (80 mm) with 5 mm chamfers, binary STL in mm."""
    mesh = chamfered_block(edge_m, chamfer_m)
    mesh.apply_scale(1e3)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    mesh.export(path, file_type="stl")
    return Path(path)
