"""The truth world: command a pose, hook and tighten the wire, solve the static equilibrium.

A :class:`Rig` owns one compiled MuJoCo scene. It behaves like the lab: the controller holds
the commanded pose (the joint springs' reference), the operator hooks the wire to a ring and
turns the ring until the wire carries the target tension, and the robot settles under gravity,
springs and wire. Everything read back (true block pose, deflections, the F/T sensor's wrench)
comes from MuJoCo.

The equilibrium is found by Newton's method on the generalized-force residual
``r(q) = qfrc_passive - qfrc_bias (+ applied)`` at zero velocity, over every degree of freedom of
the model, so effects that add joints (link compliance) need no change here.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from ..errors import ConvergenceError, OutOfRangeError
from ..lab import PAPER_LAB, LabSetup
from ..robots import RobotDescription, load_robot
from ..transforms import homogeneous, quat_wxyz
from . import mjcf
from .truth import RobotTruth, load_truth

RESIDUAL_TOL = 1e-9  # N*m; the floor is about ulp(q) * k = 4e-11 N*m
TENSION_TOL = 1e-6  # N


@dataclass(frozen=True)
class RigState:
    """What the world looks like at equilibrium (SI; poses in the robot base frame).

    ``sensor_wrench`` is the load that everything below the sensor puts on it (gravity of the
    tool side plus the wire), as an ATI sensor reports it: (Fx, Fy, Fz, Tx, Ty, Tz) [N, N*m]
    in the sensor frame, torques about the sensor origin.
    """

    q_cmd: np.ndarray  # (n,) DH rad
    q: np.ndarray  # (n,) DH rad, true joint angles
    deflection: np.ndarray  # (n,) rad, q - q_cmd
    qpos_all: np.ndarray  # (nq,) every dof of the world, incl. effects' joints
    flange_pose: np.ndarray  # (4, 4)
    block_pose: np.ndarray  # (4, 4) block frame B
    sensor_pose: np.ndarray  # (4, 4)
    sensor_wrench: np.ndarray  # (6,)
    wire_tension: float  # N, 0 when slack
    wire_length: float  # m
    wire_rest_length: float  # m (mjcf.SLACK_LENGTH when slack)
    wire_direction: np.ndarray  # (3,) unit vector hook -> anchor
    hook_position: np.ndarray  # (3,)
    residual: float  # N*m, max |generalized force residual|
    iterations: int


def _site_pose(data: mujoco.MjData, site_id: int) -> np.ndarray:
    return homogeneous(data.site_xmat[site_id].reshape(3, 3), data.site_xpos[site_id])


class Rig:
    """One virtual lab: a robot, its tool, the table with rings, and the wire.

    Parameters
    ----------
    robot : RobotDescription, optional
        The nominal description; defaults to the KUKA KR60-3.
    lab : LabSetup, optional
        Sensor, block, table and wire; defaults follow the paper.
    truth : RobotTruth, optional
        True joint stiffness (and settling terms); defaults to ``models/<robot>/truth.toml``.
    effects : tuple of vtestbed.world.effects.WorldEffect
        Hidden physics the paper's model leaves out (effects of size zero are ignored, so the
        world is then the clean one). Measurement-chain effects are applied by
        :func:`vtestbed.world.physics.draw_readings`, not here.
    gravity : bool
        Switch gravity off for clean-load checks.
    """

    def __init__(
        self,
        robot: RobotDescription | None = None,
        lab: LabSetup | None = None,
        effects: tuple = (),
        gravity: bool = True,
        truth: RobotTruth | None = None,
    ):
        self.robot = robot or load_robot()
        self.lab = lab or PAPER_LAB
        self.truth = truth or load_truth(self.robot.name)
        self.effects = tuple(e for e in effects if not e.is_null)
        for i, effect in enumerate(self.effects):
            effect.check_world(self.robot, self.truth, f"world.effects[{i}] ({effect.name})")
        self._joint_effects = tuple(e for e in self.effects if e.has_joint_forces)
        self.model = mjcf.build_scene_spec(self.robot, self.truth, self.lab, self.effects).compile()
        if not gravity:
            self.model.opt.gravity[:] = 0.0
        self.data = mujoco.MjData(self.model)
        m = self.model
        self._joint_qpos = np.array([m.jnt_qposadr[m.joint(n).id] for n in self.robot.joint_names])
        self._joint_dof = np.array([m.jnt_dofadr[m.joint(n).id] for n in self.robot.joint_names])
        self._site = {n: m.site(n).id for n in (mjcf.FLANGE_SITE, mjcf.BLOCK_SITE, mjcf.SENSOR_SITE)}
        self._hook_site = m.site(mjcf.WIRE_HOOK_SITE).id
        self._anchor_site = m.site(mjcf.WIRE_ANCHOR_SITE).id
        self._tendon = m.tendon(mjcf.WIRE_TENDON).id
        self._tool_body = m.body(mjcf.TOOL_BODY).id
        self._wire_geom = m.geom("wire_geom").id
        self._wire_mocap = m.body_mocapid[m.body(mjcf.WIRE_VISUAL_BODY).id]
        self._bias = np.zeros(m.nv)
        self._applied = np.zeros(m.nv)
        self._external: tuple[np.ndarray, np.ndarray] | None = None
        self.hook_name = next(iter(self.lab.block.hooks))
        self.anchor_name = next(iter(self.lab.table.anchors))
        self._q_cmd = np.zeros(self.robot.dof)
        self._q_guess = m.qpos_spring.copy()
        self.slacken_wire()

    # ------------------------------------------------------------------ commands
    def command(self, q_cmd) -> None:
        """Command a DH pose [rad]: the joint springs' reference. Checks the joint limits.

        The wire is slackened first, as an operator releases it before the robot moves.
        """
        q_cmd = self.robot.check_pose(q_cmd, field="commanded pose")
        self.slacken_wire()
        self._q_cmd = q_cmd.copy()
        self.model.qpos_spring[self._joint_qpos] = q_cmd
        self._q_guess = self.model.qpos_spring.copy()

    def hook(self, hook: str | None = None, anchor: str | None = None) -> None:
        """Attach the wire between a block hook and a table ring (names checked).

        Re-hooking leaves the wire slack, as an operator unhooks it first.
        """
        self.slacken_wire()
        if hook is not None:
            self.lab.block.hook(hook)  # checks the name, listing the valid ones
            # the hook's own site: where the block really is (a block_offset effect moves it)
            self.model.site_pos[self._hook_site] = self.model.site_pos[self.model.site(hook).id]
            self.hook_name = hook
        if anchor is not None:
            self.model.site_pos[self._anchor_site] = self.lab.table.anchor(anchor)
            self.anchor_name = anchor

    def slacken_wire(self) -> None:
        """Leave the wire slack: it applies nothing."""
        self._set_rest_length(mjcf.SLACK_LENGTH)

    def apply_external_wrench(self, force=None, torque=None) -> None:
        """Apply a constant wrench (world frame [N], [N*m]) at the block origin; None clears it."""
        if force is None and torque is None:
            self._external = None
            return
        f = np.zeros(3) if force is None else np.asarray(force, dtype=float)
        t = np.zeros(3) if torque is None else np.asarray(torque, dtype=float)
        self._external = (f, t)

    def _set_rest_length(self, rest_length: float) -> None:
        self.model.tendon_lengthspring[self._tendon] = [0.0, rest_length]
        self.model.tendon_stiffness[self._tendon] = self.lab.wire.axial_rigidity / rest_length

    # ------------------------------------------------------------------ physics
    def _residual(self, qpos: np.ndarray) -> np.ndarray:
        m, d = self.model, self.data
        d.qpos[:] = qpos
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_tendon(m, d)
        mujoco.mj_passive(m, d)
        mujoco.mj_rne(m, d, 0, self._bias)
        r = d.qfrc_passive - self._bias
        if self._joint_effects:
            r[self._joint_dof] += self._effect_forces(qpos[self._joint_qpos])
        if self._external is not None:
            self._applied[:] = 0.0
            point = d.site_xpos[self._site[mjcf.BLOCK_SITE]]
            mujoco.mj_applyFT(m, d, *self._external, point, self._tool_body, self._applied)
            r = r + self._applied
        return r

    def generalized_force(self, qpos) -> np.ndarray:
        """(nv,) net generalized force [N*m] at ``qpos`` (every dof) and zero velocity: springs,
        tendons, joint-level effects and an applied wrench minus gravity; zero at equilibrium."""
        return self._residual(np.asarray(qpos, dtype=float)).copy()

    def _effect_forces(self, q: np.ndarray) -> np.ndarray:
        """(n,) generalized force [N*m] of the joint-level effects at joint angles ``q`` [rad]."""
        deflection = q - self._q_cmd
        total = self._joint_effects[0].joint_forces(deflection)
        for effect in self._joint_effects[1:]:
            total += effect.joint_forces(deflection)
        return total

    def solve(self, max_iterations: int = 50, tol: float = RESIDUAL_TOL) -> RigState:
        """Static equilibrium under gravity, springs and wire at the current settings."""
        q = self._q_guess.copy()
        step = 1e-7
        jac = None
        r = self._residual(q)
        for it in range(1, max_iterations + 1):
            if np.max(np.abs(r)) < tol:
                self._q_guess = q.copy()
                return self._readout(q, np.max(np.abs(r)), it - 1)
            if jac is None or it % 4 == 0:  # chord method, Jacobian refreshed now and then
                jac = np.empty((q.size, q.size))
                for k in range(q.size):
                    dq = q.copy()
                    dq[k] += step
                    jac[:, k] = (self._residual(dq) - r) / step
                self._residual(q)
            try:
                q = q - np.linalg.solve(jac, r)
            except np.linalg.LinAlgError:
                break
            r = self._residual(q)
            if not np.all(np.isfinite(r)):
                break
        raise ConvergenceError(
            f"static equilibrium did not converge in {max_iterations} iterations: residual "
            f"{np.max(np.abs(r)):.3e} N*m > tolerance {tol:.1e} N*m"
        )

    def tighten(self, tension: float, max_iterations: int = 30) -> RigState:
        """Turn the ring until the wire carries ``tension`` [N] at equilibrium.

        Raises :class:`OutOfRangeError` for a tension the sensor cannot measure and
        :class:`SensorOverloadError` when the resulting wrench leaves the sensor's range.
        """
        self.lab.check_tension(tension, "wire tension")  # use slacken_wire() for no load
        self.slacken_wire()
        free = self.solve()
        ea = self.lab.wire.axial_rigidity
        # Secant iteration on the rest length; tension(L0) is smooth and monotonic.
        l_a = free.wire_length * (1.0 - tension / ea)
        l_b = free.wire_length * (1.0 - 2.0 * tension / ea)
        f_a = self._tension_at(l_a) - tension
        state = None
        for _ in range(max_iterations):
            state = self._state_at(l_b)
            f_b = state.wire_tension - tension
            if abs(f_b) < TENSION_TOL:
                self._check_sensor_range(state)
                return state
            if f_b == f_a:
                break
            l_a, l_b, f_a = l_b, l_b - f_b * (l_b - l_a) / (f_b - f_a), f_b
        raise ConvergenceError(
            f"could not tighten the wire to {tension:g} N: reached "
            f"{state.wire_tension if state else float('nan'):.6g} N"
        )

    def _state_at(self, rest_length: float) -> RigState:
        self._set_rest_length(rest_length)
        return self.solve()

    def _tension_at(self, rest_length: float) -> float:
        return self._state_at(rest_length).wire_tension

    def _check_sensor_range(self, state: RigState) -> None:
        context = (
            f"sensor wrench at wire tension {state.wire_tension:.1f} N "
            f"(hook {self.hook_name}, anchor {self.anchor_name})"
        )
        self.lab.sensor.check(state.sensor_wrench, context)

    def settle(self, duration: float = 3.0, q_start=None) -> RigState:
        """Damped dynamic settle with mj_step from ``q_start`` (default: the commanded pose).

        A cross-check of :meth:`solve`, 10-100x slower; uses a separate MjData.
        """
        m = self.model
        d = mujoco.MjData(m)
        d.qpos[:] = m.qpos_spring if q_start is None else q_start
        if self._external is not None:
            raise OutOfRangeError("settle() supports the wire and gravity only, not an external wrench")
        steps = int(round(duration / m.opt.timestep))
        if not self._joint_effects:
            mujoco.mj_step(m, d, nstep=steps)
        for _ in range(steps if self._joint_effects else 0):  # joint-level effects act through qfrc_applied
            d.qfrc_applied[self._joint_dof] = self._effect_forces(d.qpos[self._joint_qpos])
            mujoco.mj_step(m, d)
        state = self._readout(d.qpos.copy(), float(np.max(np.abs(self._residual(d.qpos.copy())))), 0)
        return state

    # ------------------------------------------------------------------ readout
    def _readout(self, qpos: np.ndarray, residual: float, iterations: int) -> RigState:
        m, d = self.model, self.data
        d.qpos[:] = qpos
        d.qvel[:] = 0.0
        mujoco.mj_forward(m, d)
        rest = float(m.tendon_lengthspring[self._tendon][1])
        length = float(d.ten_length[self._tendon])
        tension = float(m.tendon_stiffness[self._tendon] * max(length - rest, 0.0))
        hook = d.site_xpos[self._hook_site].copy()
        anchor = d.site_xpos[self._anchor_site].copy()
        direction = (anchor - hook) / np.linalg.norm(anchor - hook)
        self._place_wire_geom(hook, anchor)
        q = qpos[self._joint_qpos].copy()
        return RigState(
            q_cmd=self._q_cmd.copy(),
            q=q,
            deflection=q - self._q_cmd,
            qpos_all=qpos.copy(),
            flange_pose=_site_pose(d, self._site[mjcf.FLANGE_SITE]),
            block_pose=_site_pose(d, self._site[mjcf.BLOCK_SITE]),
            sensor_pose=_site_pose(d, self._site[mjcf.SENSOR_SITE]),
            # MuJoCo reports the wrench the parent applies to the tool; the sensor reports the
            # load on it, which is the opposite.
            sensor_wrench=-d.sensordata[:6].copy(),
            wire_tension=tension,
            wire_length=length,
            wire_rest_length=rest,
            wire_direction=direction,
            hook_position=hook,
            residual=residual,
            iterations=iterations,
        )

    def _place_wire_geom(self, hook: np.ndarray, anchor: np.ndarray) -> None:
        """Move the wire's stand-in capsule onto the segment hook -> anchor (for scans)."""
        axis = anchor - hook
        length = np.linalg.norm(axis)
        z = axis / length
        x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
        x /= np.linalg.norm(x)
        rot = np.column_stack([x, np.cross(z, x), z])
        self.data.mocap_pos[self._wire_mocap] = (hook + anchor) / 2
        self.data.mocap_quat[self._wire_mocap] = quat_wxyz(rot)
        self.model.geom_size[self._wire_geom][1] = length / 2
        mujoco.mj_kinematics(self.model, self.data)
