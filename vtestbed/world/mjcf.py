"""Build the MuJoCo truth world from a robot description, its truth and a lab setup (MjSpec).

``build_robot_spec`` gives the bare robot (``models/<robot>/<robot>.xml``);
``build_scene_spec`` adds the floor, the table and its rings, the force sensor, the target
block and the wire (``models/<robot>/scene.xml``). The committed XML files are written by
:func:`write_model_files` and a test checks that they equal the generator's output.

Joint ``joint<i>`` is a hinge about the DH z axis whose qpos is the DH angle theta_i; its
spring stiffness is the true joint stiffness (:class:`~vtestbed.world.truth.RobotTruth`) and its
spring reference (``qpos_spring``) is the commanded pose, set by :mod:`vtestbed.world.rig` at run
time.

Hidden physics (link compliance, a gravity compensator, ...) comes in as effects
(:mod:`vtestbed.world.effects`): extra hinges inserted before a body's own joint, or any other
edit of the spec; the researcher side never sees them. Effects whose size is zero are left out,
so the world is then exactly the clean one.
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

import mujoco
import numpy as np

from ..clearance import LINK_RADII  # the link shells: one definition for the world and the checks
from ..lab import LabSetup
from ..robot_lab import lab_for_robot
from ..robots import RobotDescription, robot_dir
from ..transforms import quat_wxyz
from .effects.structure import add_hinges
from .truth import RobotTruth, load_truth

# Names the rest of vtestbed relies on.
FLANGE_SITE = "flange"
SENSOR_SITE = "ft_sensor"
BLOCK_SITE = "block"
BLOCK_GEOM = "target_block"
BLOCK_MESH = "target_block_mesh"
WIRE_TENDON = "wire"
WIRE_HOOK_SITE = "wire_hook"
WIRE_ANCHOR_SITE = "wire_anchor"
WIRE_VISUAL_BODY = "wire_visual"
TOOL_BODY = "ft_tool"
SLACK_LENGTH = 100.0  # m: a dead band this long leaves the wire slack in any pose
SCANNABLE_GROUP = 0  # geom group of everything a scanner can see
MARKER_GROUP = 3  # geom group of markers that a scanner must not see


class SceneEffect(Protocol):
    """What the scene builder asks of an effect (see :class:`vtestbed.world.effects.WorldEffect`).

    ``hinges`` are inserted into a body before its own joint; ``edit_spec`` edits the spec before
    compilation (add a site, a tendon, ...). The rig solves equilibrium over every degree of
    freedom of the compiled model, so an effect that adds joints needs nothing else.
    """

    name: str

    def hinges(self, robot: RobotDescription) -> tuple: ...

    def edit_spec(self, spec: mujoco.MjSpec, robot: RobotDescription, lab: LabSetup) -> None: ...


def _new_spec(model_name: str) -> mujoco.MjSpec:
    spec = mujoco.MjSpec()
    spec.modelname = model_name
    spec.compiler.degree = False  # radians everywhere (MuJoCo defaults to degrees)
    spec.compiler.autolimits = True
    return spec


def _visual_geom(body, **kwargs):
    geom = body.add_geom(**kwargs)
    geom.contype = 0
    geom.conaffinity = 0
    geom.group = SCANNABLE_GROUP
    geom.mass = 0.0
    return geom


def _add_robot(
    spec: mujoco.MjSpec, robot: RobotDescription, truth: RobotTruth, hinges: tuple = ()
) -> mujoco.MjsBody:
    """Add the robot chain to ``spec`` (``hinges``: effects' extra hinges); returns the last link.

    Body ``link<i>`` is DH frame i (link 1 placed at ``dh0_in_base`` times the first DH
    transform); the ``flange`` site is at ``flange_in_dh`` in the last link.
    """
    base = spec.worldbody.add_body(name="base")
    base_hinges = [h for h in hinges if h.body == 0]
    if base_hinges:  # a compliant foundation moves the base: it needs its mass (a 0.3 m x 0.3 m drum)
        base.explicitinertial = True
        base.mass = max(robot.base_mass, 1.0)
        base.ipos = [0.0, 0.0, 0.15]
        side = base.mass * (3 * 0.3**2 + 0.3**2) / 12
        base.inertia = [side, side, base.mass * 0.3**2 / 2]
    add_hinges(base, base_hinges)
    _visual_geom(
        base,
        type=mujoco.mjtGeom.mjGEOM_CYLINDER,
        size=[0.25, 0.15, 0.0],
        pos=[0.0, 0.0, 0.15],
        rgba=[0.3, 0.3, 0.3, 1.0],
    )
    parent = base
    flange = robot.flange_transform
    for i, joint in enumerate(robot.joints):
        placement = robot.link_transform(i, 0.0)
        if i == 0:  # DH frame 0 sits at dh0_in_base in the base body (identity for the KR60)
            placement = robot.base_transform @ placement
        body = parent.add_body(name=f"link{i + 1}", pos=placement[:3, 3], quat=quat_wxyz(placement[:3, :3]))
        body.explicitinertial = True
        body.mass = joint.mass
        body.ipos = list(joint.com)
        if any(joint.inertia_offdiag):  # MuJoCo finds the principal axes (body iquat) itself
            body.fullinertia = [*joint.inertia_diag, *joint.inertia_offdiag]
        else:  # written as before, so that a diagonal description's XML stays byte-identical
            body.inertia = list(joint.inertia_diag)
        add_hinges(body, [h for h in hinges if h.body == i + 1])  # before the joint: they act on link i
        hinge = body.add_joint(name=joint.name, type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, 0, 1])
        hinge.range = [joint.lower, joint.upper]
        hinge.stiffness[0] = truth.stiffness[i]
        hinge.damping[0] = truth.damping[i]
        hinge.armature = truth.armature[i]
        # Visual shell from this joint's origin to the next one (or a sphere at the wrist).
        nxt = robot.link_transform(i + 1, 0.0)[:3, 3] if i + 1 < robot.dof else flange[:3, 3]
        rgba = [1.0, 0.45, 0.0, 1.0] if i % 2 == 0 else [0.9, 0.9, 0.9, 1.0]
        if np.linalg.norm(nxt) > 1e-6:
            _visual_geom(
                body,
                type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                size=[LINK_RADII[i], 0.0, 0.0],
                fromto=[0.0, 0.0, 0.0, *nxt],
                rgba=rgba,
            )
        else:
            _visual_geom(body, type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[LINK_RADII[i], 0, 0], rgba=rgba)
        parent = body
    parent.add_site(
        name=FLANGE_SITE,
        pos=flange[:3, 3],
        quat=quat_wxyz(flange[:3, :3]),
        size=[0.01, 0.0, 0.0],
        group=MARKER_GROUP,
    )
    return parent


def build_robot_spec(robot: RobotDescription, truth: RobotTruth) -> mujoco.MjSpec:
    """The bare robot: base, six links with spring joints, and the ``flange`` site."""
    spec = _new_spec(robot.name)
    _add_robot(spec, robot, truth)
    return spec


def _add_mesh_block(spec: mujoco.MjSpec, tool: mujoco.MjsBody, block, block_in_tool: np.ndarray):
    """A mesh target (:class:`vtestbed.target_mesh.MeshTarget`) as a mesh geom of ``tool``.

    Its vertices are given about the centre of the bounding cube (B's origin minus edge/2 on each
    axis), the frame the box geom has, so that what moves the box (the mounting effect) moves the
    mesh alike. MuJoCo computes the inertia from the closed surface (``exact``) for the geom's
    mass, which equals trimesh's mass properties (tests/test_target_mesh.py). Its vertices are
    float32: ray hits are off the ideal surface by up to about 5e-9 m.
    """
    half = block.edge / 2
    mesh = spec.add_mesh(name=BLOCK_MESH)
    mesh.uservert = (block.mesh.vertices + half).ravel().tolist()
    mesh.userface = block.mesh.faces.ravel().tolist()
    mesh.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_EXACT
    return _visual_geom(
        tool,
        name=BLOCK_GEOM,
        type=mujoco.mjtGeom.mjGEOM_MESH,
        meshname=BLOCK_MESH,
        pos=block_in_tool - half,
        rgba=[0.75, 0.78, 0.85, 1.0],
    )


def _add_tool(spec: mujoco.MjSpec, last_link: mujoco.MjsBody, flange: np.ndarray, lab: LabSetup) -> None:
    """The sensor and the block on the last link, at the flange pose ``flange`` (4, 4) in it."""
    sensor, block = lab.sensor, lab.block
    mount = last_link.add_body(name="ft_mount", pos=flange[:3, 3], quat=quat_wxyz(flange[:3, :3]))
    half = sensor.height / 2
    mount_geom = _visual_geom(
        mount,
        type=mujoco.mjtGeom.mjGEOM_CYLINDER,
        size=[sensor.diameter / 2, (sensor.adapter_thickness + half) / 2, 0.0],
        pos=sensor.mount_side_com_in_flange,
        rgba=[0.6, 0.6, 0.65, 1.0],
    )
    mount_geom.mass = sensor.mass_mount_side
    tool = mount.add_body(name=TOOL_BODY, pos=sensor.origin_in_flange)
    tool.add_site(name=SENSOR_SITE, size=[0.005, 0.0, 0.0], group=MARKER_GROUP)
    tool_half = _visual_geom(
        tool,
        type=mujoco.mjtGeom.mjGEOM_CYLINDER,
        size=[sensor.diameter / 2, half / 2, 0.0],
        pos=[0.0, 0.0, -half / 2],
        rgba=[0.6, 0.6, 0.65, 1.0],
    )
    tool_half.mass = sensor.mass_tool_side
    stem = _visual_geom(
        tool,
        type=mujoco.mjtGeom.mjGEOM_CYLINDER,
        size=[0.015, block.standoff / 2, 0.0],
        pos=[0.0, 0.0, block.standoff / 2],
        rgba=[0.5, 0.5, 0.5, 1.0],
    )
    stem.mass = block.stem_mass
    block_in_tool = lab.block_in_flange[:3, 3] - sensor.origin_in_flange
    if block.mesh is None:
        cube = _visual_geom(
            tool,
            name=BLOCK_GEOM,
            type=mujoco.mjtGeom.mjGEOM_BOX,  # a primitive box: ray hits exact to 1e-15 m
            size=[block.edge / 2] * 3,
            pos=block_in_tool - block.edge / 2,
            rgba=[0.75, 0.78, 0.85, 1.0],
        )
    else:
        cube = _add_mesh_block(spec, tool, block, block_in_tool)
    cube.mass = block.mass
    tool.add_site(name=BLOCK_SITE, pos=block_in_tool, size=[0.004, 0.0, 0.0], group=MARKER_GROUP)
    default_hook = next(iter(block.hooks))
    for name, pos in block.hooks.items():
        tool.add_site(name=name, pos=block_in_tool + np.array(pos), size=[0.003, 0, 0], group=MARKER_GROUP)
    tool.add_site(
        name=WIRE_HOOK_SITE,
        pos=block_in_tool + block.hook(default_hook),
        size=[0.003, 0, 0],
        group=MARKER_GROUP,
    )


def _add_table_and_wire(spec: mujoco.MjSpec, lab: LabSetup) -> None:
    table, wire = lab.table, lab.wire
    world = spec.worldbody
    _visual_geom(
        world, name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[5.0, 5.0, 0.05], rgba=[0.4, 0.45, 0.4, 1]
    )
    _visual_geom(
        world,
        name="table_top",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[table.size[0] / 2, table.size[1] / 2, 0.02],
        pos=[table.center[0], table.center[1], table.height - 0.02],
        rgba=[0.55, 0.4, 0.25, 1.0],
    )
    for name, pos in table.anchors.items():
        world.add_site(name=name, pos=pos, size=[0.01, 0.0, 0.0], group=MARKER_GROUP)
    first_anchor = next(iter(table.anchors.values()))
    world.add_site(name=WIRE_ANCHOR_SITE, pos=first_anchor, size=[0.006, 0.0, 0.0], group=MARKER_GROUP)
    tendon = spec.add_tendon(name=WIRE_TENDON)
    tendon.wrap_site(WIRE_HOOK_SITE)
    tendon.wrap_site(WIRE_ANCHOR_SITE)
    tendon.stiffness[0] = wire.axial_rigidity  # set to EA/L0 when the wire is tightened
    tendon.springlength = [0.0, SLACK_LENGTH]  # dead band: pulls only beyond L0, never pushes
    tendon.damping[0] = wire.damping
    tendon.width = wire.diameter / 2
    # The tendon is not a geom: a mocap capsule stands in for the wire so scans see it.
    visual = world.add_body(name=WIRE_VISUAL_BODY, mocap=True, pos=[0, 0, -10.0])
    _visual_geom(
        visual,
        name="wire_geom",
        type=mujoco.mjtGeom.mjGEOM_CAPSULE,
        size=[wire.diameter / 2, 3.0, 0.0],
        rgba=[0.2, 0.2, 0.2, 1.0],
    )


def build_scene_spec(
    robot: RobotDescription, truth: RobotTruth, lab: LabSetup, effects: tuple[SceneEffect, ...] = ()
) -> mujoco.MjSpec:
    """The full truth world: robot, sensor, block, table, rings and wire, plus ``effects``."""
    spec = _new_spec(f"{robot.name}_scene")
    spec.option.timestep = 2e-4
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT  # a statics rig: no contacts
    effects = tuple(e for e in effects if not e.is_null)
    last_link = _add_robot(spec, robot, truth, tuple(h for e in effects for h in e.hinges(robot)))
    _add_tool(spec, last_link, robot.flange_transform, lab)
    _add_table_and_wire(spec, lab)
    for kind, suffix in (
        (mujoco.mjtSensor.mjSENS_FORCE, "force"),
        (mujoco.mjtSensor.mjSENS_TORQUE, "torque"),
    ):
        spec.add_sensor(name=f"ft_{suffix}", type=kind, objtype=mujoco.mjtObj.mjOBJ_SITE, objname=SENSOR_SITE)
    for effect in effects:
        effect.edit_spec(spec, robot, lab)
    return spec


def model_files(robot: RobotDescription, truth: RobotTruth | None = None) -> dict[str, str]:
    """The XML texts of ``<robot>.xml`` and ``scene.xml`` (the robot's default lab,
    :func:`vtestbed.robot_lab.lab_for_robot`: the paper's for the KR60-3) as the generator produces them
    (``truth``: default the robot's ``truth.toml``)."""
    truth = truth or load_truth(robot.name)
    robot_xml = build_robot_spec(robot, truth).to_xml()
    scene_xml = build_scene_spec(robot, truth, lab_for_robot(robot)).to_xml()
    return {f"{robot.name.removeprefix('kuka_')}.xml": robot_xml, "scene.xml": scene_xml}


def write_model_files(
    robot: RobotDescription, directory: Path | None = None, truth: RobotTruth | None = None
) -> list[Path]:
    """Regenerate the committed MJCF files of ``robot``; returns the written paths."""
    directory = directory or robot_dir(robot.name)
    written = []
    for name, text in model_files(robot, truth).items():
        path = Path(directory) / name
        path.write_text(text)
        written.append(path)
    return written
