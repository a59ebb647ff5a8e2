"""The interactive 3-D view of one test (plotly): the robot, the block, the wire and the scans.

Everything is drawn from the dataset alone, as the researcher sees it, so the view works on a
lab's dataset too: the robot as segments between the nominal kinematics' joint frames at the
commanded pose, the block at the frame fitted to the unloaded scan, the fitted faces of both
scans, the clouds (subsampled) moved into the base frame with the recorded scanner pose, and the
wire along the measured force change. The wire's hook is the block hook whose moment about the
block origin best matches the measured torque change, and the wire is drawn down to the table
height of the robot's default lab (:func:`vtestbed.robot_lab.lab_for_robot`; the dataset records neither
the hook nor the ring).
Lengths in the figure are metres, in the robot base frame.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..dataset import read_setup, read_tests
from ..ply import read_ply
from ..researcher.kinematics import ArmKinematics
from ..researcher.measure import measure_arrays
from ..robot_lab import lab_for_robot
from .loader import ReportError

MAX_POINTS = 2500  # per cloud: enough to see the faces, small enough for a 10 MB page
WIRE_DEFAULT_M = 0.6  # drawn length of a wire that does not reach the table


def _face_corners(pose: np.ndarray, edge: float, k: int) -> np.ndarray:
    """(4, 3) corners [m] of face +k of a block frame ``pose``: coordinate k = 0, the others in [-edge, 0]."""
    a, b = [j for j in range(3) if j != k]
    corners = []
    for u, v in ((0, 0), (-edge, 0), (-edge, -edge), (0, -edge)):
        c = np.zeros(3)
        c[a], c[b] = u, v
        corners.append(pose[:3, :3] @ c + pose[:3, 3])
    return np.array(corners)


def _cube(pose: np.ndarray, edge: float) -> tuple[np.ndarray, list, list, list]:
    """Vertices (8, 3) and triangle indices of the block [-edge, 0]^3 in frame ``pose``."""
    grid = np.array([[x, y, z] for x in (-edge, 0) for y in (-edge, 0) for z in (-edge, 0)])
    verts = grid @ pose[:3, :3].T + pose[:3, 3]
    quads = [(0, 1, 3, 2), (4, 5, 7, 6), (0, 1, 5, 4), (2, 3, 7, 6), (0, 2, 6, 4), (1, 3, 7, 5)]
    tris = [t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))]
    i, j, k = (list(x) for x in zip(*tris))
    return verts, i, j, k


def _subsample(points: np.ndarray, n: int, seed: int) -> np.ndarray:
    if len(points) <= n:
        return points
    return points[np.sort(np.random.default_rng(seed).choice(len(points), n, replace=False))]


def _wire(block_pose: np.ndarray, force_b: np.ndarray, torque_b: np.ndarray, lab) -> tuple[str, np.ndarray]:
    """The hook that explains the measured torque best and the wire's end points (2, 3) [m]."""
    hooks = lab.block.hooks
    name = min(hooks, key=lambda h: np.linalg.norm(torque_b - np.cross(np.array(hooks[h]), force_b)))
    start = block_pose[:3, :3] @ np.array(hooks[name]) + block_pose[:3, 3]
    direction = block_pose[:3, :3] @ force_b / max(np.linalg.norm(force_b), 1e-12)
    length = WIRE_DEFAULT_M
    if direction[2] < -1e-3:  # pulls downward: to the table top
        length = (lab.table.height - start[2]) / direction[2]
    return name, np.array([start, start + length * direction])


def one_test_scene(dataset: str | Path, test_id: str | None = None, max_points: int = MAX_POINTS) -> dict:
    """The plotly figure (as a JSON-ready dict) of one test of ``dataset``.

    Parameters
    ----------
    dataset : str or Path
        A dataset folder (setup.json, tests.csv, clouds/).
    test_id : str, optional
        The test to show (default: the first identification test).
    max_points : int
        Points drawn per cloud (a reproducible random subsample).

    Returns
    -------
    dict
        ``{"figure_json": plotly figure as JSON text, "test_id": str, "hook": str, "points": [n0, n1]}``.

    Raises
    ------
    ReportError
        ``test_id`` is not a test of the dataset.
    """
    import plotly.graph_objects as go

    setup = read_setup(dataset)
    records = read_tests(dataset)
    if test_id is None:
        test_id = next((r.test_id for r in records if r.group == "identification"), records[0].test_id)
    by_id = {r.test_id: r for r in records}
    if test_id not in by_id:
        raise ReportError(f"{dataset}: test {test_id!r} is not in tests.csv; valid tests: {', '.join(by_id)}")
    record = by_id[test_id]
    kin = ArmKinematics.for_setup(setup)
    clouds = [read_ply(record.cloud_unloaded), read_ply(record.cloud_loaded)]
    m = measure_arrays(record, clouds[0], clouds[1], setup, kin)
    scanner = record.scanner_pose
    frames = [scanner @ m.frame_unloaded, scanner @ m.frame_loaded]
    edge = setup.block_edge
    fig = go.Figure()
    joints = [np.eye(4), *kin.joint_poses(m.q), kin.tool_pose(m.q)]
    arm = np.array([p[:3, 3] for p in joints])
    fig.add_trace(go.Scatter3d(x=arm[:, 0], y=arm[:, 1], z=arm[:, 2], mode="lines+markers", name="robot (nominal, commanded)",
                               line={"width": 9, "color": "#f28c28"}, marker={"size": 4, "color": "#444"}))  # fmt: skip
    verts, i, j, k = _cube(frames[0], edge)
    fig.add_trace(go.Mesh3d(x=verts[:, 0], y=verts[:, 1], z=verts[:, 2], i=i, j=j, k=k, opacity=0.35,
                            color="#8c8c8c", name="block (fitted, unloaded)", showlegend=True))  # fmt: skip
    block_b_force = m.wrench[:3]
    hook, wire = _wire(frames[0], block_b_force, m.wrench[3:], lab_for_robot(kin.robot))
    fig.add_trace(go.Scatter3d(x=wire[:, 0], y=wire[:, 1], z=wire[:, 2], mode="lines", name=f"wire ({hook}, measured force)",
                               line={"width": 4, "color": "#c00000"}))  # fmt: skip
    shown = []
    for idx, (label, color, pts, frame) in enumerate(
        (("unloaded", "#2e75b6", clouds[0], frames[0]), ("loaded", "#70ad47", clouds[1], frames[1]))
    ):
        sub = _subsample(pts, max_points, idx) @ scanner[:3, :3].T + scanner[:3, 3]
        shown.append(len(sub))
        fig.add_trace(go.Scatter3d(x=sub[:, 0], y=sub[:, 1], z=sub[:, 2], mode="markers", name=f"{label} cloud ({len(sub)} of {len(pts)} points)",
                                   marker={"size": 1.6, "color": color, "opacity": 0.6}))  # fmt: skip
        for face in range(3):
            c = _face_corners(frame, edge, face)
            fig.add_trace(go.Mesh3d(x=c[:, 0], y=c[:, 1], z=c[:, 2], i=[0, 0], j=[1, 2], k=[2, 3], color=color,
                                    opacity=0.5, name=f"fitted planes, {label}", legendgroup=label,
                                    showlegend=face == 0))  # fmt: skip
    centre = frames[0][:3, :3] @ np.full(3, -edge / 2) + frames[0][:3, 3]
    close = {
        f"scene.{a}axis.range": [float(c - 1.5 * edge), float(c + 1.5 * edge)] for a, c in zip("xyz", centre)
    }
    whole = {f"scene.{a}axis.autorange": True for a in "xyz"}
    fig.update_layout(
        height=620,
        margin={"l": 0, "r": 0, "t": 30, "b": 0},
        scene={"aspectmode": "data", "camera": {"eye": {"x": 1.3, "y": -1.7, "z": 0.7}}, "xaxis_title": "x [m]", "yaxis_title": "y [m]", "zaxis_title": "z [m]"},
        legend={"x": 0.0, "y": 1.0, "font": {"size": 11}},
        updatemenus=[{"type": "buttons", "direction": "left", "x": 1.0, "xanchor": "right", "y": 1.06,
                      "buttons": [{"label": "whole rig", "method": "relayout", "args": [whole]},
                                  {"label": "block close-up", "method": "relayout",
                                   "args": [{**close, "scene.aspectmode": "cube"}]}]}],
    )  # fmt: skip
    return {"figure_json": fig.to_json(), "test_id": test_id, "hook": hook, "points": shown}
