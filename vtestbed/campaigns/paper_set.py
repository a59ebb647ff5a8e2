"""The paper's test selection for any robot, written as a scenario file (``scenarios/<robot>_paper.toml``).

The identification tests follow Gao et al.'s recipe as ``scenarios/kr60_paper.toml`` does:
poses drawn from the high-criterion regions of the joint 2-3 map (:mod:`vtestbed.design.regions`,
criterion inv_kappa at the wrist point, which is the least-squares wrist point of an offset wrist,
docs/poses.md), joint 1 = 0 and joint 6 = 45 deg, joints 4-5 jittered around the optimum, the
block in the lab's block zone; the regions taking turns are those whose peak lies within
+-180 deg of theta_2 (a joint that turns +-360 deg repeats the map). Hooks take turns and rings
are tried nearest first (:func:`vtestbed.campaigns.posesets.hook_and_ring`); every test is checked
in the truth world (clearance, three faces scannable, F/T sensor in range, tension within the
lab's limit) by :class:`vtestbed.campaigns.posesets.FeasibilityChecker`. Validation tests are
uniform random poses within the limits that meet the same lab constraints and checks.

Angles are rounded to 0.01 deg in controller angles before they are checked, so the file holds
exactly the poses that passed. One seeded :class:`numpy.random.Generator` draws everything, so
:func:`draw` followed by :func:`render` gives the committed file byte for byte (a test checks it).

Regenerate: ``python -m vtestbed.campaigns.paper_set ur10`` (writes ``ur10_paper.toml``,
``ur10_ideal.toml`` and ``ur10_sweep_quick.toml`` under ``scenarios/``; docs/robots.md).

:mod:`vtestbed.campaigns.paper_tests` draws the ``[poses]`` and ``[load]`` tables of
``kr60_paper.toml`` with the paper lab's constants (200 N, block above 0.8 m); this module does
the same for a robot in its own lab (:func:`vtestbed.campaigns.spec.pose_set_defaults`), adds the
researcher's fit to the checks and validation tests, and writes whole files.
"""

from __future__ import annotations

import dataclasses
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..design import kappa, regions
from ..errors import VtestbedError
from ..researcher.cloud import FitParams, fit_block_frame
from ..researcher.kinematics import ArmKinematics
from ..robots import NEAR_SINGULAR
from ..scenario import parse_scenario
from ..world.physics import run_test_physics
from .posesets import FeasibilityChecker, lab_constraints, nested_plan
from .spec import pose_set_defaults

SCENARIOS_DIR = Path(__file__).resolve().parents[2] / "scenarios"
Q1_DEG, Q6_DEG = 0.0, 45.0  # joint 1 and joint 6 of the identification poses, as in the paper
DECIMALS = 2  # controller angles in the file [deg]
# The ATI SI-330-30 resolution (1/16 N, 1/528 N*m) as noise std, and a zero offset (as kr60_paper)
FT_NOISE_STD = (0.0625, 0.0625, 0.0625, 0.0019, 0.0019, 0.0019)
FT_BIAS = (1.5, -0.8, 2.0, 0.05, -0.03, 0.02)


class ResearcherChecker(FeasibilityChecker):
    """:class:`FeasibilityChecker` plus the researcher's own cloud fit on both noise-free scans.

    The world's scan check asks for 100 points on each of three faces; the researcher's fit
    (:func:`vtestbed.researcher.cloud.fit_block_frame`) also refuses a face that spans less than
    half the block edge. A test passes here only if each noise-free face spans ``min_extent_fraction``
    of the edge (0.6: a margin for dropouts and noise over the fit's 0.5).
    """

    def __init__(self, scenario, min_extent_fraction: float = 0.6):
        super().__init__(scenario)
        self.fit_params = FitParams(edge_m=self.lab.block.edge, min_extent_fraction=min_extent_fraction)
        self.fit_refused = 0

    def check(self, q, hook: str, anchor: str, tension: float) -> str | None:
        key = (np.asarray(q, dtype=float).tobytes(), hook, anchor, float(tension), "fit")
        if key not in self.cache:
            why = super().check(q, hook, anchor, tension)
            if why is None:
                phys = run_test_physics(self.rig, q, hook, anchor, tension, self.distance, self.placement,
                                        clearance="off")  # fmt: skip
                for state, hits in ((phys.unloaded, phys.hits_unloaded), (phys.loaded, phys.hits_loaded)):
                    nominal = np.linalg.inv(phys.scanner.pose_world) @ state.block_pose
                    try:
                        fit_block_frame(hits.points_m, nominal, self.fit_params)
                    except VtestbedError as exc:
                        self.fit_refused += 1
                        why = f"{type(exc).__name__}: {exc}"
                        break
            self.cache[key] = why
        return self.cache[key]


@dataclass(frozen=True)
class PaperSetSpec:
    """What to draw: robot (a ``models/`` folder), seed, test counts, tension [N], scanner stand-off [m]."""

    robot: str
    seed: int = 2023
    n_tests: int = 20
    n_validation: int = 5
    tension_N: float = 80.0
    scanner_distance_m: float = 0.43
    pool: int = 200  # region poses drawn; the first n_tests feasible ones are kept
    max_random_draws: int = 2000  # validation candidates drawn at most
    quick_pool: int = 150  # the quick campaign's campaign.pose_sets.pool


@dataclass(frozen=True)
class PaperSet:
    """The drawn tests: controller angles [deg], hooks, rings, and per identification test its
    region and criterion value."""

    spec: PaperSetSpec
    display_name: str
    angles_deg: np.ndarray  # (n_tests, 6) controller
    regions: tuple[str, ...]
    inv_kappa: np.ndarray
    hooks: tuple[str, ...]
    anchors: tuple[str, ...]
    val_angles_deg: np.ndarray  # (n_validation, 6) controller
    val_hooks: tuple[str, ...]
    val_anchors: tuple[str, ...]
    notes: dict
    max_tension_N: float  # the lab's largest tension and what sets it (docs/lab.md)
    max_tension_source: str


def base_data(spec: PaperSetSpec, name: str) -> dict:
    """The scenario mapping the tests are checked in: the robot, its lab and the scanner's stand-off
    (one placeholder pose; the checks take each test's pose, hook, ring and tension)."""
    poses = [[Q1_DEG, 45.0, -90.0, 90.0, 90.0, Q6_DEG]]
    return {"name": name, "robot": spec.robot, "seed": spec.seed,
            "poses": {"convention": "controller", "angles_deg": poses},
            "scanner": {"distance_m": spec.scanner_distance_m}}  # fmt: skip


def rounded_pose(robot, q_dh: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(controller angles rounded [deg], the DH pose they give [rad])."""
    deg = np.round(np.degrees(robot.dh_to_controller(q_dh)), DECIMALS) + 0.0  # no -0.0
    return deg, robot.controller_to_dh(np.radians(deg))


def draw(spec: PaperSetSpec) -> PaperSet:
    """Draw and check the tests of ``spec`` (deterministic: one seeded generator)."""
    scenario = parse_scenario(base_data(spec, "draw"))
    robot, lab = scenario.robot, scenario.lab
    opts = dataclasses.replace(pose_set_defaults(lab), pool=spec.pool, tension_N=spec.tension_N)
    lab.check_tension(spec.tension_N, f"PaperSetSpec({spec.robot!r}).tension_N")
    rng = np.random.default_rng(spec.seed)
    opt = kappa.optimize(robot, point="wrist", seed=0, q1=np.radians(Q1_DEG), q6=np.radians(Q6_DEG))
    pmap = regions.joint_plane_map(robot, opt.q, "wrist", step_deg=1.0)
    cons = lab_constraints(opts)
    found = regions.restrict(regions.find_regions(pmap, threshold=opts.threshold), pmap, robot, cons)
    select = [r.name for r in found if r.excluded is None and abs(r.peak[0]) <= np.pi]
    if not select:
        raise VtestbedError(f"{robot.display_name}: no usable region within +-180 deg of theta_2")
    pool = regions.sample_poses(robot, pmap, found, spec.pool, rng, select=select, constraints=cons,
                                wrist_jitter_deg=opts.wrist_jitter_deg, threshold=opts.threshold)  # fmt: skip
    origin = {}

    def stream(qs):
        for q in qs:
            deg, q_dh = rounded_pose(robot, q)
            if np.all((q_dh >= robot.lower) & (q_dh <= robot.upper)) and cons.ok(robot, q_dh)[0]:
                if robot.jacobian_conditioning(q_dh, lab.block_in_flange[:3, 3]) >= NEAR_SINGULAR:
                    origin[q_dh.tobytes()] = deg
                    yield q_dh

    checker, kin = ResearcherChecker(scenario), ArmKinematics(robot, lab.block_in_flange)
    region_of = {}
    for q, name in zip(pool.q, pool.regions):
        region_of[rounded_pose(robot, q)[1].tobytes()] = name
    plan = nested_plan("kappa_regions", stream(pool.q), spec.n_tests, checker, kin, spec.tension_N)
    low, high = (
        np.maximum(robot.lower, -np.pi),
        np.minimum(robot.upper, np.pi),
    )  # one turn: as a lab writes them
    uniform = (rng.uniform(low, high) for _ in range(spec.max_random_draws))
    val = nested_plan("random", stream(uniform), spec.n_validation, checker, kin, spec.tension_N)
    return PaperSet(
        spec, robot.display_name, np.array([origin[q.tobytes()] for q in plan.q]),
        tuple(region_of[q.tobytes()] for q in plan.q), kappa.inv_kappa_batch(robot, plan.q, "wrist"),
        plan.hooks, plan.anchors, np.array([origin[q.tobytes()] for q in val.q]), val.hooks, val.anchors,
        {"regions": select, "identification": plan.notes, "validation": val.notes, "truth_checks": checker.tried,
         "fit_refused": checker.fit_refused}, *lab.max_tension,
    )  # fmt: skip


def toml_rows(angles, comments=None) -> str:
    lines = []
    for i, row in enumerate(angles):
        text = "    [" + ", ".join(f"{v:7.2f}" for v in row) + "],"
        lines.append(text + (f"  # {comments[i]}" if comments else ""))
    return "\n".join(lines)


def toml_strings(values) -> str:
    return "[" + ", ".join(f'"{v}"' for v in values) + "]"


VARIANTS = {
    "paper": "The paper's method: VTOP 200B scanner and ATI SI-330-30 noise figures",
    "ideal": "The paper's method with perfect sensors: what remains is the model's own bias",
    "sweep_quick": "Smoke-test campaign: 2 pose sets x 2 scanner noise levels x 2 test counts, 5 trials each",
}
QUICK_CAMPAIGN = """
# The campaign: the file above is the base scenario (the paper's method on this robot); the cells
# are the product of the axes; every trial's seed derives from campaign.seed (see docs/sweep.md).
# Generated pose sets take the tension and block zone of the robot's lab (docs/lab.md).
[campaign]
seed = 1
trials = 5
paired = true   # common random numbers across cells

[campaign.axes]
pose_set = ["scenario", "kappa_regions"]
scanner_noise_scale = [0.5, 2.0]
n_tests = [4, 8]

[campaign.pose_sets]
pool = {pool}   # region poses drawn: most fail the checks in this lab (docs/robots.md)
tension_N = {tension:g}
"""


def render(ps: PaperSet, variant: str = "paper") -> str:
    """The scenario file's text: ``variant`` "paper", "ideal" (perfect scanner and F/T sensor, as
    kr60_ideal.toml) or "sweep_quick" (the paper variant with a small ``[campaign]``)."""
    s, ideal = ps.spec, variant == "ideal"
    name, what = f"{s.robot}_{variant}", VARIANTS[variant]
    comments = [
        f"{r} inv_kappa {k:.3f} {h} {a}" for r, k, h, a in zip(ps.regions, ps.inv_kappa, ps.hooks, ps.anchors)
    ]
    kept = {r: ps.regions.count(r) for r in ps.notes["regions"]}
    regions_text = ", ".join(f"{r} ({n} kept)" for r, n in kept.items())
    if ideal:
        sensors = "[scanner]\ndistance_m = {d:g}\nnoise = false\n\n[force_sensor]\nnoise_std = [{z}]\nbias = [{z}]\n"
        sensors = sensors.format(d=s.scanner_distance_m, z=", ".join(["0.0"] * 6))
    else:
        sensors = (f"[scanner]\ndistance_m = {s.scanner_distance_m:g}   # the lab's stand-off (docs/lab.md), "
                   "rounded\nnoise = true            # VTOP 200B defaults (paper Table 3): see "
                   "vtestbed/world/scan_noise.py\n\n[force_sensor]\n# ATI SI-330-30 resolution (1/16 N, 1/528 N*m) "
                   f"taken as the noise standard deviation\nnoise_std = [{', '.join(str(v) for v in FT_NOISE_STD)}]\n"
                   f"bias = [{', '.join(str(v) for v in FT_BIAS)}]   # a zero offset; loaded minus unloaded "
                   "cancels it\n")  # fmt: skip
    return f"""# Generated by `python -m vtestbed.campaigns.paper_set {s.robot}` (vtestbed/campaigns/paper_set.py):
# regenerate rather than edit; a test checks that this file is what the generator writes.
name = "{name}"
description = "{what}, on the {ps.display_name} in its own lab ({s.n_tests} tests, {s.tension_N:g} N)"
robot = "{s.robot}"
seed = {s.seed}

# {s.n_tests} test poses, controller angles [deg] (models/{s.robot}/robot.toml), drawn with seed {s.seed} from the
# high-criterion regions of the joint 2-3 map within +-180 deg of theta_2, taking turns:
# {regions_text}
# (criterion inv_kappa >= 0.7 at the least-squares wrist point, docs/poses.md "Offset wrists";
# DH theta_1 = {Q1_DEG:g} and theta_6 = {Q6_DEG:g} deg as in the paper, joints 4-5 jittered +-30 deg around the
# optimum, the block in the lab's block zone), kept when they pass the checks: clearance, three
# faces scannable from {s.scanner_distance_m:g} m, F/T sensor in range at {s.tension_N:g} N (the truth world), and the
# researcher's plane fit on both noise-free clouds (docs/robots.md, "The UR10 end to end").
[poses]
convention = "controller"
angles_deg = [
{toml_rows(ps.angles_deg, comments)}
]

# Per test: the block hook, the table ring (hooks take turns, nearest feasible ring) and the wire
# tension: {s.tension_N:g} N of the lab's largest {ps.max_tension_N:.4g} N ({ps.max_tension_source}, docs/lab.md).
[load]
hook = {toml_strings(ps.hooks)}
anchor = {toml_strings(ps.anchors)}
tension_N = {s.tension_N:g}

# Validation (predicted against measured, as the paper's Table 6 and Figure 11): uniform random
# poses within the joint limits (DH angles within +-180 deg) that pass the same constraints and checks.
[validation]
convention = "controller"
angles_deg = [
{toml_rows(ps.val_angles_deg)}
]
hook = {toml_strings(ps.val_hooks)}
anchor = {toml_strings(ps.val_anchors)}
tension_N = {s.tension_N:g}

[identification]
method = "fgls"   # "ols" is the paper's estimator

{sensors}""" + (
        QUICK_CAMPAIGN.format(tension=s.tension_N, pool=s.quick_pool) if variant == "sweep_quick" else ""
    )


def write(spec: PaperSetSpec, folder: Path = SCENARIOS_DIR) -> list[Path]:
    """Draw once, write ``<robot>_<variant>.toml`` for every variant into ``folder``."""
    ps, out = draw(spec), []
    for variant in VARIANTS:
        path = Path(folder) / f"{spec.robot}_{variant}.toml"
        path.write_text(render(ps, variant))
        out.append(path)
    print(ps.notes)
    return out


SPECS = {"ur10": PaperSetSpec("ur10")}  # the committed files' settings


def main(argv: list[str]) -> int:
    """Write the files of each robot named in ``argv`` (all of :data:`SPECS` when empty); 2 on bad input."""
    unknown = [name for name in argv if name not in SPECS]
    if unknown:
        print(f"paper_set: unknown robot {unknown[0]!r}; valid names: {', '.join(sorted(SPECS))} "
              "(add a PaperSetSpec to SPECS for another robot)", file=sys.stderr)  # fmt: skip
        return 2
    try:
        for robot_name in argv or sorted(SPECS):
            print(write(SPECS[robot_name]))
    except VtestbedError as exc:
        print(f"paper_set: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
