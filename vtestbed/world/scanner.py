"""A synthetic structured-light scanner (TECHLEGO VTOP 200B, paper Table 3) that ray-casts MuJoCo.

The scanner is a pinhole sensor with a pose in the world. Its frame ``S`` has the origin at the
optical centre, ``z`` along the optical axis (into the scene), ``x`` along the image rows and
``y`` down the image. One ray leaves the optical centre per measured point, through a regular
grid on the normalised image plane (``u = x/z``, ``v = y/z``) whose pitch gives the configured
point spacing at the stand-off distance. The measuring volume is the pyramid of the measuring
area at the stand-off distance, cut at ``stand-off -/+ depth/2`` (and at the datasheet's working
distance 100-1250 mm); the operator may crop it further to a scan window around the block.

Every scannable geom of the scene (the block, the F/T sensor, the flange, the wrist, the wire's
stand-in capsule, the table) occludes and returns points, exactly as it would in the lab.

Ray casting and noise are separate steps so that Monte Carlo runs can redraw the noise on one
geometry: ``hits = scanner.cast(model, data)`` (deterministic) then
``points = noise.apply(hits, rng)`` (random, :class:`ScanNoise`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property

import mujoco
import numpy as np

from ..errors import OutOfRangeError, ScanError, check_range
from ..lab import (
    DEFAULT_SCAN_DEPTH_M,
    DEFAULT_SCANNER_DISTANCE_M,
    DEFAULT_VIEW_DIRECTION,
    LabSetup,
    ScannerSpec,
)
from ..transforms import homogeneous
from .mjcf import BLOCK_GEOM, BLOCK_SITE, SCANNABLE_GROUP
from .scan_noise import ScanGeometry, ScanNoise

FACE_LABELS = ("+x", "-x", "+y", "-y", "+z", "-z")


def _check_pose(pose, name: str) -> np.ndarray:
    pose = np.array(pose, dtype=float)
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
        raise OutOfRangeError(f"{name} must be a finite 4x4 homogeneous transform, got shape {pose.shape}")
    rot = pose[:3, :3]
    if np.abs(rot.T @ rot - np.eye(3)).max() > 1e-9 or np.linalg.det(rot) < 0:
        raise OutOfRangeError(f"{name}: the 3x3 block is not a rotation (R^T R = I, det R = +1 required)")
    pose[3] = (0.0, 0.0, 0.0, 1.0)
    pose.flags.writeable = False
    return pose


@dataclass(frozen=True, eq=False)
class Scanner:
    """A configured, placed scanner.

    Parameters
    ----------
    pose_world : (4, 4) array
        Pose of the scanner frame S in the world (= robot base) frame, m.
    spec : ScannerSpec
        Datasheet limits.
    standoff_m : float
        Nominal working distance [m] along the optical axis, within the datasheet's 0.1-1.25 m.
    area_m : (float, float)
        Measuring area (width along x, height along y) [m] at the stand-off, within the datasheet's
        0.050 x 0.038 to 0.450 x 0.342 m.
    depth_m : float
        Depth of the measuring volume [m], centred on the stand-off (an assumption: the datasheet
        gives none).
    point_spacing_m : float
        Distance between neighbouring points [m] on a plane facing the scanner at the stand-off,
        0.02-0.5 mm and no finer than one camera pixel.
    window : (u_min, u_max, v_min, v_max) or None
        Scan window (region of interest) on the normalised image plane; None scans the whole field.
    block_geom : str
        Name of the target block's geom (used only for the truth-side checks of :meth:`cast`).
    """

    pose_world: np.ndarray
    spec: ScannerSpec = field(default_factory=ScannerSpec)
    standoff_m: float = DEFAULT_SCANNER_DISTANCE_M
    area_m: tuple[float, float] = (0.450, 0.342)
    depth_m: float = DEFAULT_SCAN_DEPTH_M
    point_spacing_m: float = 0.5e-3
    window: tuple[float, float, float, float] | None = None
    block_geom: str = BLOCK_GEOM

    def __post_init__(self):
        spec = self.spec
        object.__setattr__(self, "pose_world", _check_pose(self.pose_world, "scanner pose_world"))
        check_range("scanner standoff_m", self.standoff_m, *spec.working_distance_m, "m")
        for i, axis in enumerate(("width", "height")):
            check_range(
                f"scanner area_m ({axis})", self.area_m[i], spec.area_min_m[i], spec.area_max_m[i], "m"
            )
        check_range("scanner depth_m", self.depth_m, 1e-3, spec.working_distance_m[1], "m")
        check_range("scanner point_spacing_m", self.point_spacing_m, *spec.point_spacing_m, "m")
        pixel = self.area_m[0] / spec.resolution_px[0]
        if self.point_spacing_m < pixel * (1 - 1e-9):
            raise OutOfRangeError(
                f"scanner point_spacing_m = {self.point_spacing_m:g} m is finer than one camera pixel "
                f"({self.area_m[0]:g} m / {spec.resolution_px[0]} px = {pixel:.3g} m); use a coarser "
                "spacing or a smaller measuring area"
            )
        object.__setattr__(self, "area_m", tuple(float(x) for x in self.area_m))
        if self.window is not None:
            object.__setattr__(self, "window", tuple(float(x) for x in self.window))
            u0, u1, v0, v1 = self.window
            hu, hv = self.half_field
            if not (-hu <= u0 < u1 <= hu and -hv <= v0 < v1 <= hv):
                raise OutOfRangeError(
                    f"scanner window = {self.window} must satisfy -{hu:.4g} <= u_min < u_max <= {hu:.4g} "
                    f"and -{hv:.4g} <= v_min < v_max <= {hv:.4g} (the field of view)"
                )

    # ------------------------------------------------------------------ geometry
    @property
    def half_field(self) -> tuple[float, float]:
        """Half field of view as tangents (u, v): half the measuring area over the stand-off."""
        return self.area_m[0] / (2 * self.standoff_m), self.area_m[1] / (2 * self.standoff_m)

    @property
    def depth_range_m(self) -> tuple[float, float]:
        """(near, far) limits [m] of the measuring volume along the optical axis."""
        lo, hi = self.spec.working_distance_m
        return max(lo, self.standoff_m - self.depth_m / 2), min(hi, self.standoff_m + self.depth_m / 2)

    @cached_property
    def ray_directions(self) -> np.ndarray:
        """(M, 3) unit directions of every ray of a scan, in the scanner frame (row-major in v, u)."""
        step = self.point_spacing_m / self.standoff_m
        hu, hv = self.half_field
        u0, u1, v0, v1 = self.window if self.window is not None else (-hu, hu, -hv, hv)
        us = np.arange(np.ceil(u0 / step), np.floor(u1 / step) + 1) * step
        vs = np.arange(np.ceil(v0 / step), np.floor(v1 / step) + 1) * step
        uu, vv = np.meshgrid(us, vs)
        dirs = np.stack([uu.ravel(), vv.ravel(), np.ones(uu.size)], axis=1)
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        dirs.flags.writeable = False
        return dirs

    @cached_property
    def _world_rays(self) -> np.ndarray:
        return np.ascontiguousarray(self.ray_directions @ self.pose_world[:3, :3].T).ravel()

    def to_scanner(self, points_world: np.ndarray) -> np.ndarray:
        """(N, 3) world points [m] expressed in the scanner frame."""
        return (np.asarray(points_world, dtype=float) - self.pose_world[:3, 3]) @ self.pose_world[:3, :3]

    def check_in_volume(self, points_s: np.ndarray, what: str = "block") -> None:
        """Raise :class:`ScanError` unless all (N, 3) points (scanner frame) lie in the measuring volume."""
        pts = np.asarray(points_s, dtype=float).reshape(-1, 3)
        (near, far), (hu, hv), z = self.depth_range_m, self.half_field, pts[:, 2]
        u0, u1, v0, v1 = self.window if self.window is not None else (-hu, hu, -hv, hv)
        with np.errstate(divide="ignore", invalid="ignore"):
            u, v = pts[:, 0] / z, pts[:, 1] / z
        in_field = (z > 0) & (np.abs(u) <= hu) & (np.abs(v) <= hv)
        in_window = in_field & (u >= u0) & (u <= u1) & (v >= v0) & (v <= v1)
        problems = []
        if np.any(z < near):
            problems.append(f"closer than the near limit (z down to {z.min():.4f} m < {near:.4f} m)")
        if np.any(z > far):
            problems.append(f"beyond the far limit (z up to {z.max():.4f} m > {far:.4f} m)")
        if not in_field.all():
            problems.append(
                f"outside the field of view (the {self.area_m[0] * 1e3:.0f} x {self.area_m[1] * 1e3:.0f} mm "
                f"measuring area at {self.standoff_m:.3f} m)"
            )
        elif not in_window.all():
            problems.append("outside the scan window (region of interest) set at placement")
        if problems:
            inside = int(np.sum(in_window & (z >= near) & (z <= far)))
            raise ScanError(
                f"{what} {'wholly' if inside == 0 else 'partly'} outside the measuring volume of the "
                f"{self.spec.name}: {inside} of {len(pts)} corners inside; corners {'; '.join(problems)}. "
                "Move the scanner or the block."
            )

    # ------------------------------------------------------------------ placement
    @classmethod
    def place(
        cls,
        lab: LabSetup,
        block_pose_world: np.ndarray,
        distance_m: float = DEFAULT_SCANNER_DISTANCE_M,
        view_direction_block=DEFAULT_VIEW_DIRECTION,
        up_world=(0.0, 0.0, 1.0),
        roi_margin_m: float | None = 0.015,
        max_incidence_deg: float = 70.0,
        **kwargs,
    ) -> Scanner:
        """Place the scanner as an operator would: at ``distance_m`` from the block centre, looking at it.

        Parameters
        ----------
        lab : LabSetup
            Gives the block edge (the block occupies [-edge, 0]^3 in its frame B) and the table.
        block_pose_world : (4, 4) array
            Nominal (unloaded) pose of B in the world [m].
        distance_m : float
            Distance from the optical centre to the block centre [m]; it becomes the stand-off.
            Every corner of the block must lie in the measuring depth
            (:meth:`LabSetup.check_scanner_distance`: 0.17-1.18 m for the paper's block).
        view_direction_block : (3,) array
            Direction from the block centre to the scanner, in B. All three components must be
            positive so that the +x, +y and +z faces are seen; (1, 1, 1) sees them equally.
        up_world : (3,) array
            World direction that appears "up" (-y) in the image.
        roi_margin_m : float or None
            Scan window = the block's image plus this margin [m] at the block; None: whole field.
        max_incidence_deg : float
            Largest incidence angle [deg] at which a face counts as visible.
        **kwargs
            Further :class:`Scanner` fields (``area_m``, ``depth_m``, ``point_spacing_m``, ``spec``).
        """
        block_pose_world = _check_pose(block_pose_world, "block_pose_world")
        spec = kwargs.setdefault("spec", lab.scanner)
        view = np.asarray(view_direction_block, dtype=float)
        if view.shape != (3,) or not np.all(np.isfinite(view)) or np.linalg.norm(view) == 0:
            raise OutOfRangeError(
                f"view_direction_block must be a non-zero 3-vector, got {np.asarray(view_direction_block).tolist()}"
            )
        # the lab's one rule: every corner of the block within the measuring depth, at any pose
        lab_seen = lab if spec == lab.scanner else replace(lab, scanner=spec)
        depth = kwargs.get("depth_m", DEFAULT_SCAN_DEPTH_M)
        distance_m = lab_seen.check_scanner_distance(
            distance_m, "distance_m (scanner stand-off)", view, depth
        )
        view = view / np.linalg.norm(view)
        hidden = [f"+{a}" for a, c in zip("xyz", view) if c <= np.cos(np.radians(max_incidence_deg))]
        if hidden:
            angles = np.degrees(np.arccos(np.clip(view, -1, 1)))
            raise ScanError(
                f"fewer than three block faces visible from view_direction_block = {np.round(view, 3).tolist()}: "
                f"face(s) {', '.join(hidden)} seen at incidence {np.round(angles, 1).tolist()} deg "
                f"(> {max_incidence_deg:g} deg); all three components must be clearly positive"
            )
        rot_b, edge = block_pose_world[:3, :3], lab.block.edge
        centre = block_pose_world[:3, 3] + rot_b @ np.full(3, -edge / 2)
        position = centre + distance_m * (rot_b @ view)
        z_axis = -(rot_b @ view)
        up = np.asarray(up_world, dtype=float)
        y_axis = -(up - (up @ z_axis) * z_axis)
        if np.linalg.norm(y_axis) < 1e-6:  # looking straight up or down
            y_axis = np.cross(z_axis, [1.0, 0.0, 0.0])
        y_axis /= np.linalg.norm(y_axis)
        pose = homogeneous(np.column_stack([np.cross(y_axis, z_axis), y_axis, z_axis]), position)
        table = lab.table
        over_table = all(abs(position[i] - table.center[i]) <= table.size[i] / 2 for i in (0, 1))
        floor = table.height if over_table else 0.0
        if position[2] <= floor:
            raise ScanError(
                f"scanner placed at z = {position[2]:.3f} m, below the {'table top' if over_table else 'floor'} "
                f"(z = {floor:g} m): choose a shorter distance_m (now {distance_m:g} m) or a pose that holds "
                "the block higher (or, calling Scanner.place, another view_direction_block)"
            )
        scanner = cls(pose_world=pose, standoff_m=distance_m, **kwargs)
        corners = np.array([[x, y, z] for x in (0, -edge) for y in (0, -edge) for z in (0, -edge)])
        corners_s = scanner.to_scanner(block_pose_world[:3, 3] + corners @ rot_b.T)
        scanner.check_in_volume(corners_s, "block (nominal pose)")
        if roi_margin_m is None:
            return scanner
        margin = check_range("roi_margin_m", roi_margin_m, 0.0, 1.0, "m") / distance_m
        u, v = corners_s[:, 0] / corners_s[:, 2], corners_s[:, 1] / corners_s[:, 2]
        hu, hv = scanner.half_field
        window = (max(-hu, u.min() - margin), min(hu, u.max() + margin))
        window += (max(-hv, v.min() - margin), min(hv, v.max() + margin))
        return cls(pose_world=pose, standoff_m=distance_m, window=window, **kwargs)

    # ------------------------------------------------------------------ scanning
    def cast(self, model: mujoco.MjModel, data: mujoco.MjData, min_face_points: int = 100) -> ScanGeometry:
        """Ray-cast the scene in its current state (after ``mj_forward`` / a rig solve).

        Returns the noise-free hits inside the measuring volume, in the scanner frame. Raises
        :class:`ScanError` when the block is not wholly inside the measuring volume (scan window
        included) or fewer than three of its faces return ``min_face_points`` points. The block's
        extent is its box's corners or its mesh's vertices; its faces are those of the block frame
        B (the ``block`` site; without one, the geom's frame).
        """
        try:
            block_id = model.geom(self.block_geom).id
        except KeyError:
            raise ScanError(f"the scene has no geom named {self.block_geom!r} (scanner block_geom)") from None
        rot_g = data.geom_xmat[block_id].reshape(3, 3)
        mesh = model.geom_dataid[block_id] if model.geom_type[block_id] == mujoco.mjtGeom.mjGEOM_MESH else -1
        if mesh >= 0:  # a mesh target: its vertices (geom frame), the exact hull of what is cast
            start = model.mesh_vertadr[mesh]
            local = model.mesh_vert[start : start + model.mesh_vertnum[mesh]].astype(float)
        else:
            signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
            local = signs * model.geom_size[block_id]
        corners_w = data.geom_xpos[block_id] + local @ rot_g.T
        self.check_in_volume(self.to_scanner(corners_w), "block")
        try:  # the faces are the block frame B's (a mesh geom's own frame is its principal axes)
            rot_g = data.site_xmat[model.site(BLOCK_SITE).id].reshape(3, 3)
        except KeyError:
            pass

        rays = self._world_rays
        n = rays.size // 3
        geom_ids = np.empty(n, dtype=np.int32)
        dist = np.empty(n)
        normals = np.empty(3 * n)
        groups = np.zeros(6, dtype=np.uint8)
        groups[SCANNABLE_GROUP] = 1
        near, far = self.depth_range_m
        cutoff = far * float(1.0 / self.ray_directions[:, 2].min())
        origin = np.ascontiguousarray(self.pose_world[:3, 3])
        mujoco.mj_multiRay(model, data, origin, rays, groups, 1, -1, geom_ids, dist, normals, n, cutoff)
        dirs = self.ray_directions
        z = dist * dirs[:, 2]
        keep = np.flatnonzero((geom_ids >= 0) & (z >= near) & (z <= far))
        rot = self.pose_world[:3, :3]
        hits = ScanGeometry(
            points_m=dist[keep, None] * dirs[keep],
            directions=dirs[keep],
            normals=normals.reshape(-1, 3)[keep] @ rot,
            geom_ids=geom_ids[keep],
            ray_index=keep,
        )
        self._check_faces(hits, block_id, rot_g, min_face_points)
        return hits

    def _check_faces(self, hits: ScanGeometry, block_id: int, rot_g: np.ndarray, min_points: int) -> None:
        mask = hits.geom_ids == block_id
        local = hits.normals[mask] @ self.pose_world[:3, :3].T @ rot_g  # normals in the geom frame
        axis = np.argmax(np.abs(local), axis=1)
        along = local[np.arange(len(axis)), axis]
        face = 2 * axis + (along < 0)
        # only hits on a face, within 10 deg of its axis (a chamfer's are not)
        counts = np.bincount(face[np.abs(along) > np.cos(np.radians(10.0))], minlength=6)
        seen = [f"{FACE_LABELS[i]}: {counts[i]}" for i in range(6) if counts[i] > 0]
        if np.sum(counts >= min_points) < 3:
            raise ScanError(
                f"fewer than three block faces visible in the scan (need {min_points} points on each of three "
                f"faces; points per face of the block geom: {', '.join(seen) or 'none'}). The block is occluded "
                "or seen edge-on: move the scanner."
            )

    def scan(
        self,
        model: mujoco.MjModel,
        data: mujoco.MjData,
        rng: np.random.Generator | None,
        noise: ScanNoise | None = None,
    ) -> np.ndarray:
        """One scan: (N, 3) points [m] in the scanner frame; ``noise=None`` is a perfect scanner."""
        hits = self.cast(model, data)
        return hits.points_m.copy() if noise is None else noise.apply(hits, rng)
