"""The truth world's readout: what the F/T sensor, the wire and the block look like at a solved
equilibrium (:class:`RigReadout`, a part of :class:`vtestbed.world.rig.Rig`).

Units SI; poses (4, 4) in the robot base frame; the sensor's wrench in the sensor frame, torques
about the sensor origin (:class:`vtestbed.world.rig_state.RigState`). Kept apart from the solver in
``rig.py`` because it is the one place where MuJoCo's own sensors are read, and they need the
forces the solver adds in Python (:meth:`RigReadout._forces_for_readout`).
"""

from __future__ import annotations

import math
import operator

import mujoco
import numpy as np

from ..errors import SensorOverloadError
from . import mjcf
from .rig_state import RigState


class RigReadout:
    """The readout half of :class:`vtestbed.world.rig.Rig` (a mixin: it reads the MuJoCo model,
    data, views and ids that ``Rig.__init__`` sets, and the rig's lab, wire and external wrench).
    """

    def _forces_for_readout(self, qpos: np.ndarray) -> None:
        """Give MuJoCo the forces the residual adds in Python, so that its forward dynamics sees the
        equilibrium too (``qacc`` = 0) before the F/T sensor is read.

        MuJoCo's force/torque sensors are acceleration-stage sensors: the wrench a body transmits
        comes from the subtree's accelerations and the body forces on it. The joint-level effects
        (a coupling, a cubic spring) act through the residual only; left out of ``qfrc_applied``
        they leave MuJoCo an unbalanced joint torque, hence an acceleration, and the sensor read
        the subtree's inertia times it (0.35 N and 0.17 N*m with the realistic coupling at 250 N
        until 2026-12-01: docs/effects.md, tests/test_world_effects.py). Joint torques reach the
        sensor only through that acceleration, so with them applied it reads what the tool really
        transmits. An external wrench (a test's stand-in for the wire) is a body force on the tool,
        where the sensor sees it.
        """
        d = self.data  # nothing else sets these two: the solver's residual adds the forces itself
        if self._joint_effects:
            d.qfrc_applied[self._joint_dof] = self._effect_forces(qpos[self._joint_qpos])
        if self._external is not None:
            mujoco.mj_kinematics(self.model, d)  # the block site and the tool's centre of mass
            force, torque = self._external
            lever = d.site_xpos[self._site[mjcf.BLOCK_SITE]] - d.xipos[self._tool_body]
            d.xfrc_applied[self._tool_body] = np.concatenate([force, torque + np.cross(lever, force)])
        elif self._external_in_data:
            d.xfrc_applied[self._tool_body] = 0.0
        self._external_in_data = self._external is not None

    def _readout(self, qpos: np.ndarray, residual: float, iterations: int) -> RigState:
        # Hot (twice per test): few numpy calls, each costs ~1 us here, as much as mj_forward.
        m, d, t = self.model, self.data, self._tendon
        self._qpos[:] = qpos
        self._qvel[:] = 0.0
        self._forces_for_readout(qpos)
        mujoco.mj_forward(m, d)
        rest = float(self._ten_spring[t, 1])
        length = float(d.ten_length[t])
        tension = float(self._ten_stiffness[t] * max(length - rest, 0.0))
        site_xpos = d.site_xpos
        hook, anchor = site_xpos[self._hook_site].copy(), site_xpos[self._anchor_site]
        axis = anchor - hook
        half_length = math.sqrt(axis @ axis) / 2
        # the wire's stand-in capsule onto the segment hook -> anchor (for scans), its z axis along
        # the wire (its roll about the axis does not show: it is round)
        d.mocap_pos[self._wire_mocap] = (hook + anchor) / 2
        mujoco.mju_quatZ2Vec(d.mocap_quat[self._wire_mocap], axis)
        m.geom_size[self._wire_geom, 1] = half_length
        mujoco.mj_kinematics(m, d)
        flange, block, sensor = self._site_poses(d)
        q = qpos[self._joint_qpos]
        state = object.__new__(RigState)  # RigState(...) without the frozen __init__'s 15 setattr calls
        state.__dict__.update(
            q_cmd=self._q_cmd.copy(),
            q=q,
            deflection=q - self._q_cmd,
            qpos_all=qpos.copy(),
            flange_pose=flange,
            block_pose=block,
            sensor_pose=sensor,
            # MuJoCo reports the wrench the parent applies to the tool; the sensor reports the
            # load on it, which is the opposite.
            sensor_wrench=-d.sensordata[:6],
            wire_tension=tension,
            wire_length=length,
            wire_rest_length=rest,
            wire_direction=axis / (2 * half_length),
            hook_position=hook,
            residual=residual,
            iterations=iterations,
        )
        return state

    def _check_sensor_range(self, state: RigState) -> None:
        limits = self.lab.sensor.wrench_range
        if all(map(operator.le, map(abs, state.sensor_wrench.tolist()), limits)):
            return  # in range (NaN is not): the full check below only names the failing axis
        context = (
            f"sensor wrench at wire tension {state.wire_tension:.1f} N "
            f"(hook {self.hook_name}, anchor {self.anchor_name})"
        )
        try:
            self.lab.sensor.check(state.sensor_wrench, context)
        except SensorOverloadError as exc:  # what run_test_physics needs to state the valid tension
            exc.tension, exc.wrench = state.wire_tension, state.sensor_wrench.copy()
            raise
