"""Static equilibrium at zero velocity: safeguarded Newton on a MuJoCo model, converged at round-off.

The rig (:mod:`vtestbed.world.rig`) owns the residual, the net generalized force
``r(q) = qfrc_passive - qfrc_bias (+ joint-level effects, + an applied wrench)`` at ``qvel = 0``
[N*m], which vanishes at equilibrium. This module holds what does not depend on the robot:

Tangent stiffness ``K = -dr/dq`` (nv, nv) [N*m/rad]
    Everything MuJoCo computes (joint springs, tendon springs such as the wire or a balancer,
    gravity, the hinges effects insert) comes from :func:`mujoco_tangent`: at ``qvel = qacc = 0``
    MuJoCo's inverse dynamics force is ``qfrc_bias - qfrc_passive = -r``, so the position
    derivative ``mujoco.mjd_inverseFD`` returns is ``K`` (transposed: MuJoCo stores d out / d in
    row-wise per input). One call is nv + 1 passes of the pipeline in C. Forces computed in Python
    (the joint-level effects, an applied wrench) are differenced by their owner and added.
Round-off tolerance (:func:`roundoff_tolerance`)
    A fixed absolute tolerance sits at round-off for some robots and far above it for others. The
    residual's floor is what the round-off of the inputs and of the arithmetic makes of it: every
    joint angle carries about ``eps (|q_j| + 1 rad)`` (``eps |q_j|`` in the spring's ``q - q_ref``,
    ``eps`` absolute in the trigonometry of the kinematics), which moves ``r_i`` by
    ``sum_j |K_ij| eps (|q_j| + 1)``; the sums that build ``r_i`` add ``eps`` times the size of the
    forces summed (``|qfrc_bias_i| + |qfrc_passive_i| + ...``). Newton converges when every
    component is within :data:`FLOOR_FACTOR` times that floor, which scales with the robot.
Safeguarded Newton (:func:`newton`)
    Full steps ``dq = K^-1 r`` while the scaled residual ``||r / tol||`` falls; a step that does not
    lower it first refreshes a stale tangent, then halves (a backtracking line search). The tangent
    is refreshed when a step reduced the residual by less than :data:`REFRESH_RATIO` (a strongly
    nonlinear effect such as a hardening joint). A cold solve may start from a cheap ``estimate``
    of the tangent instead (the springs' part; a chord step), which is then treated as stale.
    Requires ``nq == nv`` (hinges and slides only).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numpy as np
from scipy.linalg.lapack import dgetrf, dgetri  # scipy.linalg is loaded by the world already

from ..errors import ConvergenceError

EPS = float(np.finfo(float).eps)
# Measured on the KR60 (benchmarks/bench_equilibrium.py): the residual reachable by Newton sits at
# up to ~4 floors; 16 leaves a 4x margin and still pins q to ~1e-13 rad.
FLOOR_FACTOR = 16.0
FD_STEP = 1e-6  # rad: forward step of mjd_inverseFD; truncation ~ step * |d2r/dq2| ~ 1e-5 * |K|
REFRESH_RATIO = 0.01  # refresh the tangent when one Newton step reduced the residual by less than this
MIN_STEP = 1.0 / 64.0  # the line search gives up below this fraction of a Newton step
_DSBL_CONSTRAINT = int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)  # an int: enum arithmetic is slow


@dataclass(frozen=True)
class Equilibrium:
    """A converged static equilibrium.

    Attributes
    ----------
    qpos : (nq,) array
        Every degree of freedom [rad or m].
    residual : (nv,) array
        The generalized-force residual there [N*m].
    tolerance : (nv,) array
        The per-component tolerance it met [N*m].
    iterations : int
        Newton steps taken.
    residual_calls, tangent_calls : int
        Evaluations of the residual and of the tangent stiffness.
    tangent : (nv, nv) array
        The latest tangent stiffness [N*m/rad] (evaluated at or near ``qpos``; the ``estimate``
        when the solve needed no exact one).
    inverse : (nv, nv) array or None
        Its inverse [rad/(N*m)], when the solver formed it.
    """

    qpos: np.ndarray
    residual: np.ndarray
    tolerance: np.ndarray
    iterations: int
    residual_calls: int
    tangent_calls: int
    tangent: np.ndarray
    inverse: np.ndarray | None = None


def mujoco_tangent(model: mujoco.MjModel, data: mujoco.MjData, qpos: np.ndarray) -> np.ndarray:
    """(nv, nv) tangent stiffness ``-d(qfrc_passive - qfrc_bias)/dq`` [N*m/rad] at ``qpos``, qvel = 0.

    Forward differences of MuJoCo's inverse dynamics (``mjd_inverseFD``, step :data:`FD_STEP`).
    Constraints (joint limits) are switched off for the call: the static residual has none, and a
    limit touched by a finite-difference step would add its penalty stiffness. ``data`` is left at
    ``qpos`` with ``qvel = qacc = 0``; its derived quantities are those of the last FD pass.
    """
    data.qpos[:] = qpos
    data.qvel[:] = 0.0
    data.qacc[:] = 0.0
    dfdq = np.empty((model.nv, model.nv))
    opt = model.opt
    flags = opt.disableflags
    opt.disableflags = flags | _DSBL_CONSTRAINT
    try:
        mujoco.mjd_inverseFD(model, data, FD_STEP, False, dfdq, None, None, None, None, None, None)
    finally:
        opt.disableflags = flags
    return dfdq.T  # MuJoCo's layout: row i holds d(qfrc_inverse)/d q_i


def joint_spring_tangent(model: mujoco.MjModel) -> np.ndarray:
    """(nv, nv) diagonal stiffness [N*m/rad] of the model's joint springs (the robot's joints and
    the hinges effects insert)."""
    k = np.zeros((model.nv, model.nv))
    k[model.jnt_dofadr, model.jnt_dofadr] = model.jnt_stiffness
    return k


def spring_tangent(model: mujoco.MjModel, data: mujoco.MjData, joint_springs: np.ndarray) -> np.ndarray:
    """(nv, nv) the tangent stiffness without its geometric terms [N*m/rad], for a cold solve.

    ``joint_springs`` (:func:`joint_spring_tangent`) plus each taut tendon's axial stiffness
    ``k_t J_t J_t^T`` (the wire, a balancer), with the tendons ``data`` holds (an
    ``mj_tendon`` at the pose). Left out are gravity's stiffness and the turning of forces with
    the pose (the wire's and a balancer's direction, an applied wrench): about 2e-3 of the springs
    on the KR60 and the UR10 (median over random tests, 7e-3 at worst), so Newton with this
    estimate gains 2-3 digits a step without the nv + 1 pipeline passes of :func:`mujoco_tangent`.
    """
    k = joint_springs.copy()
    springs, stiffness = model.tendon_lengthspring, model.tendon_stiffness
    for t in range(model.ntendon):
        length = data.ten_length[t]
        if stiffness[t] > 0.0 and not springs[t, 0] <= length <= springs[t, 1]:  # taut
            jac = tendon_jacobian(model, data, t)
            k += stiffness[t] * (jac[:, None] * jac)
    return k


def roundoff_tolerance(tangent: np.ndarray, qpos: np.ndarray, force_scale: np.ndarray) -> np.ndarray:
    """(nv,) tolerance [N*m] on each residual component: FLOOR_FACTOR times its round-off floor.

    Parameters
    ----------
    tangent : (nv, nv) array
        Tangent stiffness ``K`` [N*m/rad].
    qpos : (nv,) array
        Joint coordinates [rad].
    force_scale : (nv,) array
        Sum of the magnitudes of the generalized forces added to form ``r`` [N*m]
        (``|qfrc_bias| + |qfrc_passive| + ...``).

    Returns
    -------
    (nv,) array
        ``FLOOR_FACTOR * eps * (|K| @ (|q| + 1) + force_scale)`` [N*m].
    """
    return FLOOR_FACTOR * EPS * (np.abs(tangent) @ (np.abs(qpos) + 1.0) + force_scale)


def _inverse(tangent: np.ndarray, singular_ok: bool = False) -> np.ndarray | None:
    # An explicit inverse: each Newton step is then one matrix-vector product. LAPACK's LU
    # directly (1.7 us for 6x6 here) rather than np.linalg.inv (4.3 us, mostly its Python checks).
    # ``singular_ok``: None for a singular matrix instead of the error.
    lu, pivots, info = dgetrf(tangent)
    if info == 0:
        inverse, info = dgetri(lu, pivots)
    if info != 0 and singular_ok:
        return None
    if info != 0:
        raise ConvergenceError(
            "static equilibrium: the tangent stiffness is singular (a degree of freedom without "
            "stiffness holds no static pose)"
        )
    return inverse


def newton(
    residual: Callable[[np.ndarray], np.ndarray],
    tangent: Callable[[np.ndarray], np.ndarray],
    tolerance: Callable[[np.ndarray, np.ndarray], np.ndarray],
    q0: np.ndarray,
    max_iterations: int = 50,
    tangent0: np.ndarray | None = None,
    tangent0_exact: bool = True,
    inverse0: np.ndarray | None = None,
    estimate: Callable[[np.ndarray], np.ndarray] | None = None,
) -> Equilibrium:
    """Solve ``residual(q) = 0`` by safeguarded Newton from ``q0``.

    Parameters
    ----------
    residual : callable (nv,) -> (nv,)
        Generalized force [N*m] at ``q``; zero at equilibrium.
    tangent : callable (nv,) -> (nv, nv)
        ``-d residual / dq`` [N*m/rad] at ``q`` (exact or nearly: the line search covers the rest).
    tolerance : callable (q, K) -> (nv,)
        Per-component tolerance [N*m], evaluated with each new tangent (see
        :func:`roundoff_tolerance`). It may read what the latest ``residual`` call left behind.
    q0 : (nv,) array
        Start [rad].
    max_iterations : int
        Newton steps allowed.
    tangent0 : (nv, nv) array, optional
        A tangent at or near ``q0`` (saves the first tangent evaluation).
    tangent0_exact : bool
        Whether ``tangent0`` was evaluated at ``q0``; if not (a neighbouring state's, as when the
        wire is tightened from the unloaded equilibrium), a step it fails first refreshes it.
    inverse0 : (nv, nv) array, optional
        The inverse of ``tangent0`` when known (an earlier solve's :attr:`Equilibrium.inverse`).
    estimate : callable (nv,) -> (nv, nv), optional
        A cheap approximation of the tangent at ``q0`` (it may read what the first ``residual``
        call left behind), used instead of ``tangent`` when no ``tangent0`` is given. It is
        treated as stale: a step it fails, or one that reduces the residual by less than
        :data:`REFRESH_RATIO`, brings in ``tangent``. Newton with it is a chord method: each step
        shrinks the residual by about ``||K_est^-1 K - I||`` (2e-3 on the KR60, see
        :func:`spring_tangent`), which beats the cost of one exact tangent. A singular estimate
        is replaced by ``tangent``.

    Raises
    ------
    ConvergenceError
        When the tolerance is not met within ``max_iterations`` steps or the line search stalls;
        the message gives the worst component against its tolerance.
    """
    # Lean on purpose (a cold solve is ~60 us, a numpy call on six numbers ~0.5 us): the merit
    # ``||r / tol||`` is a Python float reused from the line search, and it decides most
    # convergence tests by itself (see :func:`_converged`).
    q = np.array(q0, dtype=float)
    r = residual(q)
    calls, tangents = 1, 0
    h = None
    if tangent0 is not None:
        k, fresh = tangent0, tangent0_exact
        h = _inverse(k) if inverse0 is None else inverse0
    elif estimate is not None:
        k, fresh = estimate(q), False
        h = _inverse(k, singular_ok=True)  # singular (a dof held by gravity alone): the exact one
    if h is None:
        k, tangents, fresh = tangent(q), 1, True
        h = _inverse(k)
    tol = tolerance(q, k)  # at the current q
    w = r / tol
    merit = math.sqrt(w @ w)
    done, it = _converged(r, tol, merit), 0
    while not done:
        if it == max_iterations:
            raise ConvergenceError(
                f"static equilibrium did not converge in {max_iterations} iterations: residual "
                f"{_worst(r, tol)}"
            )
        step, alpha = h @ r, 1.0
        while True:
            q_try = q + step if alpha == 1.0 else q + alpha * step  # 1.0 * step is step
            r_try = residual(q_try)
            calls += 1
            w_try = r_try / tol
            m_try = math.sqrt(w_try @ w_try)
            if m_try <= (1.0 - 1e-4 * alpha) * merit:  # False for NaN too
                break
            if not fresh:  # a stale tangent is the likely culprit: refresh it and retry a full step
                k, tangents, fresh = tangent(q), tangents + 1, True
                h, tol = _inverse(k), tolerance(q, k)
                w = r / tol
                merit = math.sqrt(w @ w)
                step, alpha = h @ r, 1.0
                continue
            alpha *= 0.5
            if alpha < MIN_STEP:
                raise ConvergenceError(
                    f"static equilibrium: the line search stalled after {it} iterations at residual "
                    f"{_worst(r, tol)}"
                )
        it += 1
        q, r = q_try, r_try
        done = _converged(r, tol, m_try)  # a converged point needs no new tangent
        if not done and m_try > REFRESH_RATIO * merit:  # the tangent no longer describes the force
            k, tangents, fresh = tangent(q), tangents + 1, True
            h, tol = _inverse(k), tolerance(q, k)
            w = r / tol
            merit = math.sqrt(w @ w)
            done = _converged(r, tol, merit)
        else:
            fresh, merit = False, m_try
    return Equilibrium(q, r, tol, it, calls, tangents, k, h)


def _converged(r: np.ndarray, tol: np.ndarray, merit: float) -> bool:
    """``all(|r| <= tol)``, decided by the merit ``||r / tol||`` when it can be.

    Each ``|r_i / tol_i|`` lies within ``[merit / sqrt(n), merit]`` up to a few ulps, so a merit
    below 0.999 proves every ``|r_i| < tol_i`` and one above ``1.001 sqrt(n)`` proves some
    ``|r_i| > tol_i``; only between (and for NaN, inf) are the components compared.
    """
    if merit < 0.999:
        return True
    if merit > 1.001 * math.sqrt(r.size):
        return False
    return bool((np.abs(r) <= tol).all())


def tendon_at(model: mujoco.MjModel, data: mujoco.MjData, qpos: np.ndarray, tendon: int):
    """``tendon``'s length [m] and its Jacobian dL/dq (nv,) [m/rad] at ``qpos``.

    Leaves ``data`` at ``qpos`` with kinematics, subtree centres and tendons computed (what the
    passive forces and ``mj_rne`` need next).
    """
    data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    mujoco.mj_tendon(model, data)
    return float(data.ten_length[tendon]), tendon_jacobian(model, data, tendon)


def tendon_jacobian(model: mujoco.MjModel, data: mujoco.MjData, tendon: int) -> np.ndarray:
    """(nv,) dense Jacobian dL/dq [m/rad] of ``tendon`` from ``data`` (after ``mj_tendon``)."""
    jac = np.zeros(model.nv)  # MuJoCo stores tendon Jacobians sparse
    adr, nnz = model.ten_J_rowadr[tendon], model.ten_J_rownnz[tendon]
    jac[model.ten_J_colind[adr : adr + nnz]] = data.ten_J[adr : adr + nnz]
    return jac


class SitePoses:
    """(4, 4) world poses of a few sites from ``data``, read with three numpy calls (a hot readout).

    Reads the span of site rows that holds them all (a handful: the scene numbers them close).
    """

    def __init__(self, site_ids: list[int]):
        low = min(site_ids)
        self._span = slice(low, max(site_ids) + 1)
        self._rows = [i - low for i in site_ids]
        self._template = np.zeros((max(site_ids) + 1 - low, 4, 4))
        self._template[:, 3, 3] = 1.0  # not transforms.homogeneous: np.eye costs more than the rest

    def __call__(self, data: mujoco.MjData) -> list[np.ndarray]:
        poses = self._template.copy()
        poses[:, :3, :3] = data.site_xmat[self._span].reshape(-1, 3, 3)
        poses[:, :3, 3] = data.site_xpos[self._span]
        return [poses[i] for i in self._rows]


def central_difference(force: Callable, x: np.ndarray, step: float = 1e-6) -> np.ndarray:
    """(m, n) ``d force / d x`` by central differences; ``force`` maps (n,) [rad] to (m,) [N*m].

    For the forces computed outside MuJoCo (joint-level effects, an applied wrench); truncation
    (step**2 times the third derivative over 6) and round-off (eps |f| / step) are ~1e-9 of the
    stiffness here.
    """
    columns = []
    for j in range(x.size):
        dx = np.zeros(x.size)
        dx[j] = step
        columns.append((force(x + dx) - force(x - dx)) / (2.0 * step))
    return np.column_stack(columns)


def _worst(r: np.ndarray, tol: np.ndarray) -> str:
    i = int(np.argmax(np.abs(r) / tol))
    return f"|r[{i}]| = {abs(r[i]):.3e} N*m > tolerance {tol[i]:.1e} N*m"
