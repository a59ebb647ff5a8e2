"""The truth world: command a pose, hook and tighten the wire, solve the static equilibrium.

A :class:`Rig` owns one compiled MuJoCo scene. It behaves like the lab: the controller holds
the commanded pose (the joint springs' reference), the operator hooks the wire to a ring and
turns the ring until the wire carries the target tension, and the robot settles under gravity,
springs and wire. Everything read back (true block pose, deflections, the F/T sensor's wrench)
comes from MuJoCo.

The equilibrium is found by Newton's method on the generalized-force residual
``r(q) = qfrc_passive - qfrc_bias (+ joint-level effects, + applied)`` at zero velocity, over every
degree of freedom of the model, so effects that add joints (link compliance) need no change here
(solver, tangent and round-off test: :mod:`vtestbed.world.statics`). Tightening holds the tension:
solve under a constant pull along the wire, then set the rest length at which the real wire pulls
exactly that; the real wire verifies the state.
"""

from __future__ import annotations

import mujoco
import numpy as np

from ..errors import ConvergenceError, OutOfRangeError, check_range
from ..lab import PAPER_LAB, LabSetup
from ..robots import RobotDescription, load_robot
from . import mjcf, statics
from .effects import check_effects
from .rig_readout import RigReadout
from .rig_state import RigState
from .truth import RobotTruth, load_truth

TENSION_TOL = 1e-6  # N; holding the tension reaches ~1e-10 N
# A constant pull T along the wire: a tendon spring of rate T / HOLD_OFFSET whose rest length is
# -HOLD_OFFSET. It pulls T (1 + L / HOLD_OFFSET), T within 2e-15 relative for a wire of L = 2 m,
# and its steps in L (ulp(1e15 m) = 0.125 m) move the pull by T * eps; its rate is nil, so the
# Newton tangent carries only the turning of the wire's direction under T.
HOLD_OFFSET = 1e15  # m


# A stiff arm deflects by milliradians (the KR60 about 1 mrad under gravity and 200 N): hidden effects
# that deflect a joint by 50 mrad (2.9 deg) make a world that no longer describes one. (A rig without
# effects on its statics is not checked: the solver's own tests scale the stiffness down 100 times,
# and an effect on the sensors alone leaves the clean rig's statics.)
MAX_DEFLECTION_RAD = 0.05


class Rig(RigReadout):
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
        # each kept effect's place in the scenario's list (null ones are dropped, not renumbered)
        self._effect_fields = tuple(f"world.effects[{i}]" for i, e in enumerate(effects) if not e.is_null)
        check_effects(effects, self.robot, self.truth)
        self._joint_effects = tuple(e for e in self.effects if e.has_joint_forces)
        self.model = mjcf.build_scene_spec(self.robot, self.truth, self.lab, self.effects).compile()
        if not gravity:
            self.model.opt.gravity[:] = 0.0
        self.data = mujoco.MjData(self.model)
        m = self.model
        self._joint_qpos = np.array([m.jnt_qposadr[m.joint(n).id] for n in self.robot.joint_names])
        self._joint_dof = np.array([m.jnt_dofadr[m.joint(n).id] for n in self.robot.joint_names])
        self._site = {n: m.site(n).id for n in (mjcf.FLANGE_SITE, mjcf.BLOCK_SITE, mjcf.SENSOR_SITE)}
        self._site_poses = statics.SitePoses(list(self._site.values()))  # flange, block, sensor
        self._hook_site = m.site(mjcf.WIRE_HOOK_SITE).id
        self._anchor_site = m.site(mjcf.WIRE_ANCHOR_SITE).id
        self._tendon = m.tendon(mjcf.WIRE_TENDON).id
        self._tool_body = m.body(mjcf.TOOL_BODY).id
        self._wire_geom = m.geom("wire_geom").id
        self._wire_mocap = m.body_mocapid[m.body(mjcf.WIRE_VISUAL_BODY).id]
        self._bias = np.zeros(m.nv)
        # views of MjData's buffers (fixed for its life): each attribute access builds a new one
        self._qpos, self._qvel, self._qfrc_passive = self.data.qpos, self.data.qvel, self.data.qfrc_passive
        self._ten_spring, self._ten_stiffness = m.tendon_lengthspring, m.tendon_stiffness  # model's too
        self._applied = np.zeros(m.nv)
        self._spring_tangent = statics.joint_spring_tangent(m)  # constant: the bulk of the tangent
        self._external: tuple[np.ndarray, np.ndarray] | None = None
        self._external_in_data = False  # data.xfrc_applied holds it (set at the last readout)
        self.hook_name = next(iter(self.lab.block.hooks))
        self.anchor_name = next(iter(self.lab.table.anchors))
        self._q_cmd = np.zeros(self.robot.dof)
        self._q_guess = m.qpos_spring.copy()
        self._tangent_guess: tuple | None = None  # the unloaded equilibrium's and its inverse, for tighten
        self.residual_calls = 0  # evaluations since construction (benchmarks read them)
        self.tangent_calls = 0
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
        self._tangent_guess = None  # a new wire state: the last tangent no longer describes it
        self._ten_spring[self._tendon] = (0.0, rest_length)
        self._ten_stiffness[self._tendon] = self.lab.wire.axial_rigidity / rest_length

    def _hold_tension(self, tension: float) -> None:
        """Replace the wire by a constant pull ``tension`` [N] along it (see HOLD_OFFSET)."""
        self._tangent_guess = None
        self._ten_spring[self._tendon] = (-HOLD_OFFSET, -HOLD_OFFSET)  # pulls at any length
        self._ten_stiffness[self._tendon] = tension / HOLD_OFFSET

    # ------------------------------------------------------------------ physics
    def _residual(self, qpos: np.ndarray) -> np.ndarray:
        self.residual_calls += 1
        m, d = self.model, self.data
        self._qpos[:] = qpos
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_tendon(m, d)
        return self._residual_tail(qpos)

    def _residual_tail(self, qpos: np.ndarray) -> np.ndarray:
        """The residual from MuJoCo's passive forces on, kinematics and tendons done at ``qpos``."""
        m, d = self.model, self.data
        mujoco.mj_passive(m, d)
        mujoco.mj_rne(m, d, 0, self._bias)
        r = self._qfrc_passive - self._bias
        if self._joint_effects:
            r[self._joint_dof] += self._effect_forces(qpos[self._joint_qpos])
        if self._external is not None:
            r += self._applied_force()
        return r

    def _applied_force(self) -> np.ndarray:
        """(nv,) generalized force [N*m] of the external wrench at the kinematics in ``data``."""
        m, d = self.model, self.data
        self._applied[:] = 0.0
        point = d.site_xpos[self._site[mjcf.BLOCK_SITE]]
        mujoco.mj_applyFT(m, d, *self._external, point, self._tool_body, self._applied)
        return self._applied

    def _applied_force_at(self, qpos: np.ndarray) -> np.ndarray:
        self.data.qpos[:] = qpos
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_comPos(self.model, self.data)  # mj_applyFT's Jacobian needs the subtree centres
        return self._applied_force().copy()

    def generalized_force(self, qpos) -> np.ndarray:
        """(nv,) net generalized force [N*m] at ``qpos`` (every dof) and zero velocity: springs,
        tendons, joint-level effects and an applied wrench minus gravity; zero at equilibrium."""
        return self._residual(np.asarray(qpos, dtype=float)).copy()

    def tangent_stiffness(self, qpos) -> np.ndarray:
        """(nv, nv) tangent stiffness ``-d generalized_force / d qpos`` [N*m/rad] at ``qpos``.

        MuJoCo's part (springs, tendons, gravity) from ``mjd_inverseFD``; the joint-level effects
        and an applied wrench by central differences (:mod:`vtestbed.world.statics`).
        """
        self.tangent_calls += 1
        qpos = np.asarray(qpos, dtype=float)
        k = self._with_effects_tangent(statics.mujoco_tangent(self.model, self.data, qpos), qpos)
        if self._external is not None:
            k -= statics.central_difference(self._applied_force_at, qpos)
        return k

    def _tangent_estimate(self, qpos: np.ndarray) -> np.ndarray:
        """A cold solve's first tangent [N*m/rad]: :func:`statics.spring_tangent` (the tendons the
        residual call at ``qpos`` left in ``data``) plus the joint-level effects'."""
        k = statics.spring_tangent(self.model, self.data, self._spring_tangent)
        return self._with_effects_tangent(k, qpos)

    def _with_effects_tangent(self, k: np.ndarray, qpos: np.ndarray) -> np.ndarray:
        """``k`` plus the joint-level effects' tangent (central differences) [N*m/rad], in place."""
        if self._joint_effects:
            jq, jd = self._joint_qpos, self._joint_dof
            k[np.ix_(jd, jd)] -= statics.central_difference(self._effect_forces, qpos[jq])
        return k

    def residual_tolerance(self, qpos) -> np.ndarray:
        """(nv,) the tolerance [N*m] :meth:`solve` asks of each residual component at ``qpos``."""
        qpos = np.asarray(qpos, dtype=float)
        tangent = self.tangent_stiffness(qpos)
        self._residual(qpos)
        return self._tolerance(qpos, tangent)

    def _tolerance(self, qpos: np.ndarray, tangent: np.ndarray) -> np.ndarray:
        """(nv,) round-off tolerance [N*m]; force sizes from the latest evaluation (they barely move)."""
        scale = np.abs(self._qfrc_passive) + np.abs(self._bias)
        if self._joint_effects:
            scale[self._joint_dof] += np.abs(self._effect_forces(qpos[self._joint_qpos]))
        if self._external is not None:
            scale += np.abs(self._applied)
        return statics.roundoff_tolerance(tangent, qpos, scale)

    def _effect_forces(self, q: np.ndarray) -> np.ndarray:
        """(n,) generalized force [N*m] of the joint-level effects at joint angles ``q`` [rad]."""
        deflection = q - self._q_cmd
        total = self._joint_effects[0].joint_forces(deflection)
        for effect in self._joint_effects[1:]:
            total += effect.joint_forces(deflection)
        return total

    def _equilibrium(
        self, q0, max_iterations: int, tol=None, tangent0=None, tangent0_exact=True, inverse0=None
    ):
        if not (isinstance(max_iterations, int) and max_iterations >= 0):
            raise OutOfRangeError(f"max_iterations = {max_iterations!r} must be an integer >= 0")
        if tol is None:
            tolerance = self._tolerance
        else:
            tol = check_range("tol", tol, 0.0, np.inf, "N*m")
            tolerance = lambda q, k: np.full(q.size, tol)  # noqa: E731
        args = (self._residual, self.tangent_stiffness, tolerance, q0, max_iterations, tangent0, tangent0_exact,
                inverse0, self._tangent_estimate)  # fmt: skip
        try:
            eq = statics.newton(*args)
        except ConvergenceError as exc:
            if softening := self._softened_joints(q0, any_softening=True):
                raise ConvergenceError(f"{exc}; {softening}") from None
            raise
        if softening := self._softened_joints(eq.qpos):
            raise OutOfRangeError(softening)
        deflection = eq.qpos[self._joint_qpos] - self._q_cmd
        j = int(np.argmax(np.abs(deflection)))
        # a clean rig may be soft on purpose, and an effect on the sensors alone leaves its statics
        physical = [e.name for e in self.effects if e.changes_physics]
        if physical and abs(deflection[j]) > MAX_DEFLECTION_RAD:
            effects = ", ".join(physical)
            raise OutOfRangeError(
                f"{self.robot.joint_names[j]} deflects {deflection[j] * 1e3:.4g} mrad "
                f"({np.degrees(deflection[j]):.3g} deg) at equilibrium, beyond {MAX_DEFLECTION_RAD * 1e3:g} mrad: "
                f"the joint springs (models/{self.robot.name}/truth.toml) and the hidden effects (world.effects: "
                f"{effects}) make a robot that sags, not the stiff arm the experiment measures; shrink the effect"
            )
        return eq

    def _softened_joints(self, qpos, any_softening: bool = False) -> str:
        """What a softening spring (``nonlinear_joint`` with k3 < 0) did at MuJoCo's ``qpos``: ""
        while every such joint's tangent stiffness stays positive (with ``any_softening``, for the
        equilibrium's own failure, any softening spring is named)."""
        deflection = qpos[self._joint_qpos] - self._q_cmd
        for field, effect in zip(self._effect_fields, self.effects):
            if getattr(effect, "k3_Nm_per_rad3", 0.0) < 0:
                k = float(self.truth.stiffness_true[effect.joint - 1])
                dq = float(deflection[effect.joint - 1])
                if any_softening or not effect.tangent_stiffness(k, dq) > 0:
                    return effect.past_peak(k, None if any_softening else dq, field)
        return ""

    def solve(self, max_iterations: int = 50, tol: float | None = None) -> RigState:
        """Static equilibrium under gravity, springs and wire at the current settings.

        Parameters
        ----------
        max_iterations : int
            Newton steps allowed.
        tol : float, optional
            An absolute tolerance [N*m] on every residual component; by default each component
            must reach its round-off floor (:func:`vtestbed.world.statics.roundoff_tolerance`).

        Raises :class:`ConvergenceError` when the tolerance is not reached.
        """
        eq = self._equilibrium(self._q_guess, max_iterations, tol)
        self._q_guess = eq.qpos.copy()
        self._tangent_guess = (eq.tangent, eq.inverse)
        return self._readout(eq.qpos, max(map(abs, eq.residual.tolist())), eq.iterations)

    def tighten(self, tension: float, max_iterations: int = 50) -> RigState:
        """Turn the ring until the wire carries ``tension`` [N] at equilibrium.

        Solves under a constant pull ``tension`` along the wire, sets the rest length at which the
        real wire pulls exactly that, and checks (or polishes by Newton) the state with the real
        wire. Raises :class:`OutOfRangeError` for a tension the sensor cannot measure,
        :class:`ConvergenceError` (the wire left slack) when it misses ``tension`` by more than
        ``TENSION_TOL`` and :class:`SensorOverloadError` when the wrench leaves the sensor's range.
        """
        self.lab.check_tension(tension, "wire tension")  # use slacken_wire() for no load
        q0, (tangent0, inverse0) = self._q_guess, self._tangent_guess or (None, None)
        self._hold_tension(tension)
        try:
            # From the unloaded equilibrium's tangent (usually the springs' estimate, 2e-3 off;
            # the held pull adds only T |d2L/dq2|, 1e-4 of the springs): 2-3 digits a step, and
            # no call of the most expensive part, the exact tangent.
            held = self._equilibrium(q0, max_iterations, None, tangent0, False, inverse0)
            length, wire_j = statics.tendon_at(self.model, self.data, held.qpos, self._tendon)
            ea = self.lab.wire.axial_rigidity
            rest = length * ea / (ea + tension)  # EA (L - L0) / L0 = T
            self._set_rest_length(rest)
            # The real wire adds its axial stiffness EA/L0 along its Jacobian; the turning of its
            # direction under the same pull is in the held tangent already.
            tangent = held.tangent + (ea / rest) * (wire_j[:, None] * wire_j)  # np.outer, cheaper
            self.residual_calls += 1
            r = self._residual_tail(held.qpos)  # the rest length moves no kinematics
            tol = self._tolerance(held.qpos, tangent)
            if (np.abs(r) <= tol).all():  # the real wire agrees: no polish
                eq = statics.Equilibrium(held.qpos, r, tol, 0, 1, 0, tangent)
            else:
                eq = self._equilibrium(held.qpos, max_iterations, tangent0=tangent)
            state = self._readout(
                eq.qpos, max(map(abs, eq.residual.tolist())), held.iterations + eq.iterations
            )
            if not abs(state.wire_tension - tension) <= TENSION_TOL:
                raise ConvergenceError(
                    f"could not tighten the wire to {tension:g} N: reached {state.wire_tension:.9g} N "
                    f"(tolerance {TENSION_TOL:g} N)"
                )
        except (ConvergenceError, OutOfRangeError):  # a world past its springs (rig._equilibrium) too
            self.slacken_wire()  # never leave the wire replaced by its held pull
            raise
        self._q_guess = eq.qpos.copy()
        self._check_sensor_range(state)
        return state

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
        return self._readout(d.qpos.copy(), float(np.max(np.abs(self._residual(d.qpos.copy())))), 0)
