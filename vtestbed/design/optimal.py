"""Experiment design on the identification problem itself: which tests identify k best?

A test t (pose, hook, ring, tension) gives ``delta_d_t = A_t c + e_t`` with ``A_t`` (6, n) from
:func:`vtestbed.identify.a_matrix` and a displacement noise ``e_t ~ N(0, Sigma_t)``,
``Sigma_t = diag(sigma_p^2 I_3, sigma_r^2 I_3)`` [m^2, rad^2]. For a set of tests the weighted
least-squares estimate of the compliances ``c = 1/k`` has::

    M = sum_t A_t^T Sigma_t^-1 A_t        (information matrix, n x n)
    cov(c) = M^-1,   std(k_j) = std(c_j) / c_j^2 = std(c_j) k_j^2   (delta method)

The criteria use the information of the relative compliance errors, ``M_rel = S M S`` with
``S = diag(c_prior)`` (a prior guess of the stiffness is needed anyway for std(k)):

* D-optimality: ``log det M_rel`` (maximise; independent of the prior),
* A-optimality: ``trace(M_rel^-1) = sum_j (std(c_j)/c_j)^2`` (minimise),
* E-optimality: ``lambda_min(M_rel)`` (maximise),
* minimax: ``max_j (M_rel^-1)_jj = max_j (std(k_j)/k_j)^2``, the worst joint's relative variance
  (minimise; the default of ``vtestbed poses design``, its convex relaxation and lower bound are in
  :mod:`vtestbed.design.minimax`).

The candidates' wrenches come from the nominal geometry (the direction from the hook to the
ring at the commanded pose), which a researcher can compute without the truth world.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from ..errors import OutOfRangeError, UnknownNameError
from ..lab import DEFAULT_TENSION_N, PAPER_LAB, LabSetup
from ..researcher.identify import a_matrix
from ..researcher.kinematics import ArmKinematics
from ..robots import RobotDescription
from .clearance import NominalClearance

# Block-displacement noise of the default scan pipeline (VTOP 200B noise model, 0.6 m, open3d fit),
# measured against the truth over 30 seeds x 8 tests (tests/test_design_optimal.py): 5.3 um, 8.5 urad.
SIGMA_P = 5.3e-6  # m, translational displacement std per axis
SIGMA_R = 8.5e-6  # rad, rotational displacement std per axis
CRITERIA = ("minimax", "D", "A", "E")
METHODS = ("greedy", "exchange")


@dataclass(frozen=True)
class CandidateTest:
    """One possible test, with its nominal wrench at the block origin (base axes)."""

    q: np.ndarray  # (6,) DH rad
    hook: str
    anchor: str
    tension: float  # N
    jacobian: np.ndarray  # (6, n) at the block origin, base axes [m | 1]
    wrench: np.ndarray  # (6,) [N, N*m] at the block origin, base axes

    @property
    def a(self) -> np.ndarray:
        """(6, n) A of the test."""
        return a_matrix(self.jacobian, self.wrench)

    def to_dict(self) -> dict:
        return {
            "q_deg": np.degrees(self.q).tolist(),
            "hook": self.hook,
            "anchor": self.anchor,
            "tension_N": self.tension,
        }


def _outward_normal(hook_b: np.ndarray, edge: float) -> np.ndarray | None:
    """Outward normal (block frame) of the face(s) the hook sits on; None if inside the block."""
    n = np.zeros(3)
    n[np.isclose(hook_b, -edge, atol=1e-9)] = -1.0
    n[np.isclose(hook_b, 0.0, atol=1e-9)] = 1.0
    return n / np.linalg.norm(n) if n.any() else None


def nominal_wrench(kin: ArmKinematics, lab: LabSetup, q, hook: str, anchor: str, tension: float):
    """Wire wrench at the block origin from the commanded pose's geometry.

    Returns ``(wrench (6,) [N, N*m] base axes, direction (3,) hook -> ring, hook (3,) [m], block (4, 4))``.
    """
    block = kin.flange_pose(q) @ lab.block_in_flange
    hook_w = block[:3, :3] @ lab.block.hook(hook) + block[:3, 3]
    ring = lab.table.anchor(anchor)
    u = (ring - hook_w) / np.linalg.norm(ring - hook_w)
    force = tension * u
    return np.concatenate([force, np.cross(hook_w - block[:3, 3], force)]), u, hook_w, block


def sensor_load(kin: ArmKinematics, lab: LabSetup, q, wrench_block: np.ndarray) -> np.ndarray:
    """The wire's wrench as the F/T sensor sees it (sensor axes, about its origin)."""
    block = kin.flange_pose(q) @ lab.block_in_flange
    sensor = kin.flange_pose(q) @ lab.sensor_in_flange
    f, tau = wrench_block[:3], wrench_block[3:]
    tau_s = tau + np.cross(block[:3, 3] - sensor[:3, 3], f)
    return np.concatenate([sensor[:3, :3].T @ f, sensor[:3, :3].T @ tau_s])


def candidate_tests(
    robot: RobotDescription,
    poses,
    hooks=None,
    anchors=None,
    tension: float = DEFAULT_TENSION_N,
    lab: LabSetup = PAPER_LAB,
    check_sensor: bool = True,
    outward: bool = True,
    clearance: bool | NominalClearance = True,
) -> tuple[CandidateTest, ...]:
    """All feasible (pose, hook, ring) combinations at one wire tension [N].

    Dropped: a pose outside the limits raises; a wire that would cut into the block
    (``outward``), a wrench outside the sensor's range (``check_sensor``) or a test that is not
    physically possible on the nominal model (``clearance``: a link on the table or the floor, the
    wire through a link, the sensor or the block's edges, the scanner's view blocked;
    :class:`vtestbed.design.clearance.NominalClearance`, docs/clearance.md) is skipped. Pass a
    ``NominalClearance`` to set the scanner's stand-off and to count the refusals (its ``refused``).
    """
    tension = lab.check_tension(tension, "tension")
    hooks = list(lab.block.hooks) if hooks is None else list(hooks)
    anchors = list(lab.table.anchors) if anchors is None else list(anchors)
    kin = ArmKinematics(robot, lab.block_in_flange)
    limit = np.asarray(lab.sensor.wrench_range)
    nominal = NominalClearance(robot, lab) if clearance is True else clearance or None
    out = []
    for i, q in enumerate(np.atleast_2d(poses)):
        q = robot.check_pose(q, field=f"candidate pose {i}")
        jac = kin.jacobian(q, frame="base")
        for hook in hooks:
            kept = []
            for anchor in anchors:
                wrench, u, _, block = nominal_wrench(kin, lab, q, hook, anchor, tension)
                normal = _outward_normal(lab.block.hook(hook), lab.block.edge)
                if outward and normal is not None and (block[:3, :3] @ normal) @ u <= 0.0:
                    continue
                if check_sensor and np.any(np.abs(sensor_load(kin, lab, q, wrench)) > limit):
                    continue
                kept.append((anchor, wrench))
            if nominal is not None and kept:  # the costliest check last, on the survivors only
                reports = nominal.check_many(q, hook, [a for a, _ in kept])
                nominal.refused += sum(not r.ok for r in reports)
                kept = [k for k, r in zip(kept, reports) if r.ok]
            out += [CandidateTest(q.copy(), hook, a, float(tension), jac, w) for a, w in kept]
    return tuple(out)


def measurement_covariance(sigma_p: float = SIGMA_P, sigma_r: float = SIGMA_R) -> np.ndarray:
    """(6, 6) displacement covariance ``diag(sigma_p^2 I_3, sigma_r^2 I_3)`` [m^2 | rad^2]."""
    if not (sigma_p > 0 and sigma_r > 0):
        raise OutOfRangeError(f"sigma_p = {sigma_p:g} m and sigma_r = {sigma_r:g} rad must both be > 0")
    return np.diag([sigma_p**2] * 3 + [sigma_r**2] * 3)


def _a_stack(tests) -> np.ndarray:
    if isinstance(tests, np.ndarray):
        a = np.asarray(tests, dtype=float)
    else:
        a = np.array([t.a if isinstance(t, CandidateTest) else np.asarray(t, dtype=float) for t in tests])
    if a.ndim != 3 or a.shape[1] != 6:
        raise OutOfRangeError(f"A matrices must have shape (T, 6, n), got {a.shape}")
    return a


def test_information(tests, sigma_p: float = SIGMA_P, sigma_r: float = SIGMA_R) -> np.ndarray:
    """(T, n, n) information ``A_t^T Sigma^-1 A_t`` of each test."""
    a = _a_stack(tests)
    w = 1.0 / np.sqrt(np.diag(measurement_covariance(sigma_p, sigma_r)))
    aw = a * w[None, :, None]
    return np.einsum("tki,tkj->tij", aw, aw)


def information_matrix(tests, sigma_p: float = SIGMA_P, sigma_r: float = SIGMA_R) -> np.ndarray:
    """(n, n) ``M = sum_t A_t^T Sigma^-1 A_t`` [(N*m/rad)^2]."""
    return test_information(tests, sigma_p, sigma_r).sum(axis=0)


def _base(base_information, n: int) -> np.ndarray:
    m0 = np.asarray(base_information, dtype=float)
    if (
        m0.shape != (n, n)
        or not np.all(np.isfinite(m0))
        or np.linalg.eigvalsh((m0 + m0.T) / 2)[0] < -1e-9 * max(1.0, np.abs(m0).max())
    ):
        raise OutOfRangeError(
            f"base_information must be a symmetric positive semi-definite ({n}, {n}) matrix"
        )
    return m0


def _prior(stiffness_prior, n: int) -> np.ndarray:
    k = np.asarray(stiffness_prior, dtype=float)
    if k.shape != (n,) or not np.all(np.isfinite(k) & (k > 0)):
        raise OutOfRangeError(
            f"stiffness_prior must be {n} positive values [N*m/rad], got {stiffness_prior!r}"
        )
    return k


def _scores(m_rel: np.ndarray, criterion: str) -> np.ndarray:
    """Scores of (..., n, n) relative information matrices; larger is better for all three."""
    if criterion == "D":
        sign, logdet = np.linalg.slogdet(m_rel)
        return np.where(sign > 0, logdet, -np.inf)
    if criterion == "A":
        try:
            return -np.trace(np.linalg.inv(m_rel), axis1=-2, axis2=-1)
        except np.linalg.LinAlgError:
            return np.array(
                [-np.inf if np.linalg.cond(m) > 1e15 else -np.trace(np.linalg.inv(m)) for m in m_rel]
            )
    if criterion == "E":
        return np.linalg.eigvalsh(m_rel)[..., 0]
    if criterion == "minimax":
        try:
            return -np.diagonal(np.linalg.inv(m_rel), axis1=-2, axis2=-1).max(axis=-1)
        except np.linalg.LinAlgError:
            return np.array(
                [-np.inf if np.linalg.cond(m) > 1e15 else -np.diag(np.linalg.inv(m)).max() for m in m_rel]
            )
    raise UnknownNameError("design criterion", criterion, CRITERIA)


@dataclass(frozen=True)
class DesignReport:
    """Design criteria and predicted uncertainty of a set of tests."""

    n_tests: int
    information: np.ndarray  # (n, n) M [(N*m/rad)^2]
    compliance_cov: np.ndarray  # (n, n) M^-1 [(rad/(N*m))^2]
    compliance_std: np.ndarray  # (n,) rad/(N*m)
    stiffness_std: np.ndarray  # (n,) N*m/rad, delta method at the prior
    relative_std: np.ndarray  # (n,) std(k_j)/k_j = std(c_j)/c_j
    d_value: float  # log det M_rel
    a_value: float  # trace M_rel^-1
    e_value: float  # lambda_min(M_rel)

    @property
    def minimax_value(self) -> float:
        """The worst joint's relative std ``max_j std(k_j)/k_j`` (the minimax criterion's square root)."""
        return float(self.relative_std.max())

    def to_dict(self) -> dict:
        return {
            "n_tests": self.n_tests,
            "d_log_det_rel": self.d_value,
            "a_trace_rel_cov": self.a_value,
            "e_min_eig_rel": self.e_value,
            "worst_relative_std_percent": self.minimax_value * 100,
            "compliance_std_rad_per_Nm": self.compliance_std.tolist(),
            "stiffness_std_Nmm_per_rad": (self.stiffness_std * 1e3).tolist(),
            "relative_std_percent": (self.relative_std * 100).tolist(),
        }


def evaluate(
    tests, stiffness_prior, sigma_p: float = SIGMA_P, sigma_r: float = SIGMA_R, base_information=None
) -> DesignReport:
    """D, A, E values and the predicted std of each joint's stiffness for a set of tests.

    ``base_information`` (n, n) [(N*m/rad)^2]: the information ``M`` of tests already made, added.
    """
    m = information_matrix(tests, sigma_p, sigma_r)
    if base_information is not None:
        m = m + _base(base_information, m.shape[0])
    k = _prior(stiffness_prior, m.shape[0])
    s = 1.0 / k
    m_rel = m * np.outer(s, s)
    if np.linalg.matrix_rank(m_rel) < m.shape[0]:
        raise OutOfRangeError(
            f"the {len(_a_stack(tests))} tests do not identify all {m.shape[0]} joints (M is singular)"
        )
    cov_rel = np.linalg.inv(m_rel)
    cov = cov_rel * np.outer(s, s)
    std_c = np.sqrt(np.diag(cov))
    return DesignReport(
        n_tests=len(_a_stack(tests)), information=m, compliance_cov=cov, compliance_std=std_c,
        stiffness_std=std_c * k**2, relative_std=std_c * k, d_value=float(np.linalg.slogdet(m_rel)[1]),
        a_value=float(np.trace(cov_rel)), e_value=float(np.linalg.eigvalsh(m_rel)[0]),
    )  # fmt: skip


@dataclass(frozen=True)
class Selection:
    """Tests chosen from candidates."""

    indices: tuple[int, ...]
    criterion: str
    method: str
    report: DesignReport
    exchanges: int  # swaps made by the exchange phase

    def to_dict(self) -> dict:
        return {"indices": list(self.indices), "criterion": self.criterion, "method": self.method,
                "exchanges": self.exchanges, **self.report.to_dict()}  # fmt: skip


def select_tests(
    candidates,
    n: int,
    stiffness_prior,
    criterion: str = "D",
    method: str = "exchange",
    sigma_p: float = SIGMA_P,
    sigma_r: float = SIGMA_R,
    max_passes: int = 20,
    base_information=None,
) -> Selection:
    """Pick ``n`` distinct tests from ``candidates`` by greedy addition, then exchange (Fedorov).

    Greedy adds the candidate that improves the criterion most (a tiny ridge makes the first
    steps well defined); the exchange phase swaps a chosen test for an unchosen one while that
    improves the criterion. Deterministic: ties go to the lowest index. ``base_information``
    (n, n) [(N*m/rad)^2]: the information of tests already made (sequential design); the criterion
    is then that of the old and the new tests together.
    """
    if criterion not in CRITERIA:
        raise UnknownNameError("design criterion", criterion, CRITERIA)
    if method not in METHODS:
        raise UnknownNameError("selection method", method, METHODS)
    info = test_information(candidates, sigma_p, sigma_r)
    n_cand, n_par = info.shape[0], info.shape[1]
    if not 1 <= n <= n_cand:
        raise OutOfRangeError(f"n = {n} tests is outside the valid range [1, {n_cand}] (the candidates)")
    s = 1.0 / _prior(stiffness_prior, n_par)
    info = info * np.outer(s, s)
    ridge = 1e-9 * np.trace(info.mean(axis=0)) / n_par * np.eye(n_par)
    if base_information is not None:  # tests already made (sequential design)
        ridge = ridge + _base(base_information, n_par) * np.outer(s, s)
    chosen: list[int] = []
    total = ridge.copy()
    for _ in range(n):
        scores = _scores(total[None] + info, criterion)
        scores[chosen] = -np.inf
        best = int(np.argmax(scores))
        chosen.append(best)
        total = total + info[best]
    swaps = 0
    if method == "exchange":
        chosen, swaps = exchange(info, chosen, total, criterion, max_passes)
    tests = _a_stack(candidates)[chosen]
    report = evaluate(tests, 1.0 / s, sigma_p, sigma_r, base_information)
    return Selection(tuple(chosen), criterion, method, report, swaps)


def exchange(info: np.ndarray, chosen: list[int], total: np.ndarray, criterion: str, max_passes: int = 20):
    """Fedorov exchange: swap a chosen test for an unchosen one while that improves the criterion.

    ``info`` (T, n, n): each candidate's relative information; ``chosen``: the start (indices);
    ``total`` (n, n): their sum plus any fixed part (ridge, tests already made). Deterministic: ties
    go to the lowest index. Returns the chosen indices and the number of swaps.
    """
    chosen = list(chosen)
    current = _scores(total[None], criterion)[0]
    swaps = 0
    for _ in range(max_passes):
        improved = False
        for pos in range(len(chosen)):
            base = total - info[chosen[pos]]
            scores = _scores(base[None] + info, criterion)
            scores[chosen] = -np.inf
            best = int(np.argmax(scores))
            if scores[best] > current + 1e-12 * max(1.0, abs(current)):
                chosen[pos], total, current = best, base + info[best], scores[best]
                swaps, improved = swaps + 1, True
        if not improved:
            break
    return chosen, swaps


def scenario_toml(tests) -> str:
    """The ``[poses]`` and ``[load]`` tables of a scenario file for these tests (DH angles in deg)."""
    tests = list(tests)
    if not tests:
        raise OutOfRangeError("scenario_toml needs at least one test")
    rows = ",\n".join("    [" + ", ".join(f"{v:9.4f}" for v in np.degrees(t.q)) + "]" for t in tests)
    tensions = {t.tension for t in tests}
    tension = (
        f"{tensions.pop():g}"
        if len(tensions) == 1
        else "[" + ", ".join(f"{t.tension:g}" for t in tests) + "]"
    )
    return (
        '[poses]\nconvention = "dh"\nangles_deg = [\n' + rows + ",\n]\n\n[load]\n"
        f"hook = [{', '.join(json.dumps(t.hook) for t in tests)}]\n"  # TOML basic strings share JSON's escapes
        f"anchor = [{', '.join(json.dumps(t.anchor) for t in tests)}]\n"
        f"tension_N = {tension}\n"
    )
