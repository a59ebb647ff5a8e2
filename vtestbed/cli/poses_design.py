"""``vtestbed poses design`` and ``vtestbed poses next``: choose tests (minimax by default, with the
relaxation's lower bound), or the paper's kappa selection; and the next tests after an identified
dataset, with its estimate as the prior (sequential design). Every command prints JSON.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..design import minimax, regions
from ..design import optimal as design
from ..design.clearance import NominalClearance
from ..design.pool import NoFeasibleTestError, candidate_pool, kappa_selection, random_poses
from ..design.priors import NAMED_PRIORS, stiffness_prior
from ..design.refine import MAX_ROUNDS, refine_design
from ..design.sequential import next_tests, noise_from_residuals
from ..errors import DatasetError, OutOfRangeError, UnknownNameError, VtestbedError
from ..robot_lab import lab_for_robot
from ..robots import load_robot
from .args import SEED, integer, number, output_dir, parse_numbers
from .poses import _emit, _point, _read_poses, _regions_and_poses

POOLS = ("random", "regions")


def _prior(text: str, dof: int) -> np.ndarray:
    """A named prior, or ``dof`` comma-separated values in N*mm/rad (the paper's unit)."""
    if text in NAMED_PRIORS:
        return stiffness_prior(text, dof, "--stiffness-prior")
    if not any(c.isdigit() for c in text):
        raise UnknownNameError("--stiffness-prior", text, NAMED_PRIORS)
    values = parse_numbers(text, "--stiffness-prior", dof, "N*mm/rad")
    if not np.all(values > 0):
        raise OutOfRangeError(
            f"--stiffness-prior must be {dof} positive stiffness values [N*mm/rad], got {text!r}"
        )
    return stiffness_prior(values / 1e3, dof, "--stiffness-prior")


def _names(text: str | None, option: str, kind: str, valid) -> list[str] | None:
    """The comma-separated names of ``option`` (None: all), each one of ``valid``."""
    if not text:
        return None
    names = text.split(",")
    for name in names:
        if name not in valid:
            raise UnknownNameError(f"{option} {kind}", name, valid)
    return names


def _cmd_design(args) -> int:
    robot = load_robot(args.robot)
    lab = lab_for_robot(robot)  # the paper's lab scaled to the robot (PAPER_LAB for the KR60-3)
    if args.tension is not None:
        lab.check_tension(args.tension, "--tension")
    kappa_sel = args.criterion == "kappa"
    if args.refine and (args.criterion != "minimax" or args.no_bound):
        raise OutOfRangeError(
            f"--refine {args.refine} grows the pool for the minimax design with its bound; it does not apply "
            f"to --criterion {args.criterion}{' with --no-bound' if args.no_bound else ''} (valid: --criterion "
            "minimax without --no-bound, or --refine 0)"
        )
    pool_kind = "regions" if kappa_sel else args.pool
    if args.poses or pool_kind != "regions":  # a random pool or a poses file: the regions' options unused
        given = [name for name, default in args.region_defaults.items() if getattr(args, name) != default]
        if given:
            option = "--" + given[0].replace("_", "-")
            raise OutOfRangeError(
                f"{option} shapes the kappa-regions pool; it does not apply to "
                f"{'--poses' if args.poses else '--pool ' + pool_kind} (valid: --pool regions or --criterion "
                f"kappa, or leave {option} out)"
            )
    n_poses = args.n if args.n is not None else (max(40, 3 * args.tests) if pool_kind == "regions" else 400)
    args.n = n_poses
    if args.poses:
        q, pool_kind = _read_poses(args.poses, robot), "file"
    elif pool_kind == "regions":
        q = _regions_and_poses(robot, args)[2].q
    else:
        q = random_poses(robot, lab, n_poses, np.random.default_rng(args.seed))
    hooks = _names(args.hooks, "--hooks", "hook", lab.block.hooks)
    anchors = _names(args.anchors, "--anchors", "anchor", lab.table.anchors)
    nominal = False if args.no_clearance else NominalClearance(robot, lab, lab.scanner_distance)
    prior = _prior(args.stiffness_prior, robot.dof)
    data = {"criterion": args.criterion, "pool": pool_kind, "sigma_p_m": args.sigma_p, "sigma_r_rad": args.sigma_r,
            "stiffness_prior": args.stiffness_prior, "stiffness_prior_Nmm_per_rad": (prior * 1e3).tolist(),
            "clearance_check": not args.no_clearance}  # fmt: skip
    if kappa_sel:  # the paper's selection, one test per region pose, at one tension
        tension = lab.check_tension(args.tension or lab.default_tension_N, "--tension")
        chosen = kappa_selection(robot, q, args.tests, tension, lab, nominal)
        report = design.evaluate(chosen, prior, args.sigma_p, args.sigma_r)
        data |= {"selection": {"method": "paper (kappa regions, draw order)", **report.to_dict()}}
    else:
        try:
            cands = candidate_pool(robot, lab, poses=q, max_tension=args.tension, levels=args.tension_levels,
                                   hooks=hooks, anchors=anchors, clearance=nominal)  # fmt: skip
        except NoFeasibleTestError as exc:  # the only refusal that other poses or options can cure
            raise VtestbedError(f"{exc} (robot {robot.name!r}; try other poses, --hooks/--anchors, "
                                "or --no-clearance)") from None  # fmt: skip
        if args.refine:  # grow the pool around the design's poses (design/refine.py)
            grown = refine_design(robot, cands, args.tests, prior, np.random.default_rng([args.seed, 1]), lab,
                                  args.refine, sigma_p=args.sigma_p, sigma_r=args.sigma_r)  # fmt: skip
            result, cands = grown.result, grown.pool
            data["refine"] = grown.to_dict()
        else:
            result = minimax.design(cands.a, args.tests, prior, args.criterion, args.sigma_p, args.sigma_r,
                                    bound=not args.no_bound)  # fmt: skip
        chosen = [cands.tests[i] for i in result.selection.indices]
        data |= {"candidates": len(cands), "candidate_pool": cands.to_dict(), **result.to_dict()}
        rep = result.selection.report
        if result.relaxation is not None:
            data["chosen_over_bound"] = result.ratio
            if args.criterion == "minimax":
                data["lower_bound_worst_relative_std_percent"] = float(np.sqrt(result.relaxation.bound)) * 100
        data["worst_relative_std_percent"] = rep.minimax_value * 100
    data |= {"wrist": regions.wrist_report(robot, np.array([t.q for t in chosen]), _point(args.point)),
             "tests": [t.to_dict() for t in chosen]}  # fmt: skip
    if args.out:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        how = "the paper's kappa selection" if kappa_sel else f"{args.criterion}-optimal"
        header = f"# {args.tests} tests chosen by 'vtestbed poses design' ({how})\n"
        name = f'name = "design_{args.criterion}_{args.tests}"\nrobot = "{robot.name}"\n\n'
        (Path(args.out) / "design_scenario.toml").write_text(header + name + design.scenario_toml(chosen))
    _emit(args, data, "design.json")
    return 0


def _cmd_next(args) -> int:
    from ..dataset_identification import identify_dataset
    from ..researcher.measure import stacked

    setup, measurements, result = identify_dataset(args.dataset, method=args.method)
    robot = load_robot(setup.robot)
    lab = lab_for_robot(robot)  # the paper's lab scaled to the robot (PAPER_LAB for the KR60-3)
    if args.tension is not None:
        lab.check_tension(args.tension, "--tension")
    made = [m for m in measurements if m.group == "identification"]
    jac, wrench, _ = stacked(made)
    sigma_p, sigma_r = args.sigma_p, args.sigma_r
    if sigma_p is None or sigma_r is None:  # what is not given comes from the residuals
        residual_p, residual_r = _residual_noise(args.dataset, result, len(made))
        sigma_p, sigma_r = sigma_p or residual_p, sigma_r or residual_r
    nominal = False if args.no_clearance else NominalClearance(robot, lab, lab.scanner_distance)
    cands = candidate_pool(robot, lab, args.n, np.random.default_rng(args.seed), max_tension=args.tension,
                           levels=args.tension_levels, clearance=nominal)  # fmt: skip
    nxt = next_tests(jac, wrench, result.stiffness, args.tests, cands, sigma_p, sigma_r, args.criterion)
    data = {"dataset": str(args.dataset), "robot": robot.name, "method": args.method,
            "candidate_pool": cands.to_dict(), **nxt.to_dict()}  # fmt: skip
    if args.out:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        header = (f"# {args.tests} next tests after {args.dataset} ({len(made)} tests), chosen by "
                  f"'vtestbed poses next' ({args.criterion}, prior = the dataset's estimate)\n")  # fmt: skip
        name = f'name = "next_{args.criterion}_{args.tests}"\nrobot = "{robot.name}"\n\n'
        (Path(args.out) / "next_scenario.toml").write_text(header + name + design.scenario_toml(nxt.tests))
    _emit(args, data, "next.json")
    return 0


def _residual_noise(dataset, result, n_tests: int) -> tuple[float, float]:
    """(sigma_p [m], sigma_r [rad]) from the identification's residuals, or an error that says why
    not and what to do. One test gives 6 equations for 6 unknowns: its residuals are round-off
    (1e-19), not noise, so fewer than 2 tests are refused even when round-off happens to be > 0."""
    try:
        if n_tests >= 2:
            return noise_from_residuals(result.component_std)
    except OutOfRangeError:
        pass
    raise DatasetError(
        f"{dataset}: {n_tests} identification test(s) leave no residual to estimate the measurement"
        " noise from (one test gives 6 equations for the 6 stiffnesses; at least 2 noisy tests are"
        " needed); add tests, or give the noise: --sigma-p M --sigma-r RAD"
    )


def _noise_args(p) -> None:
    p.add_argument("--sigma-p", type=number(0, 1, "m", low_open=True), default=design.SIGMA_P,
                   help="displacement std [m] (default %(default)s)")  # fmt: skip
    p.add_argument("--sigma-r", type=number(0, 1, "rad", low_open=True), default=design.SIGMA_R,
                   help="rotation std [rad] (default %(default)s)")  # fmt: skip


REGION_OPTIONS = ("step_deg", "threshold", "min_height", "box", "select", "wrist_jitter_deg")


def add_design_parsers(cmds, common, lab_args) -> None:
    """Register ``poses design`` and ``poses next`` (``common``, ``lab_args``: the group's shared options)."""
    p = cmds.add_parser(
        "design", help="choose tests: minimax (default), D/A/E-optimal, or the paper's kappa selection"
    )
    common(p)
    lab_args(p)
    p.set_defaults(n=None)  # poses to draw: 400 random, or max(40, 3 x --tests) from the regions
    # the options that shape the kappa-regions pool, with their defaults (refused with another pool)
    p.set_defaults(region_defaults={name: p.get_default(name) for name in REGION_OPTIONS})
    p.add_argument("--poses", help="poses.json (from 'poses regions'); default: draw --n poses (see --pool)")
    p.add_argument("--pool", choices=POOLS, default="random",
                   help="random: --n poses uniform in the joint limits, block in the lab zone (default); "
                        "regions: the kappa regions (the paper's)")  # fmt: skip
    p.add_argument("--hooks", help="comma-separated hooks (default all)")
    p.add_argument("--anchors", help="comma-separated rings (default all)")
    p.add_argument("--tension", type=number(0, 1e5, "N"), default=None,
                   help="top wire tension [N] (default: the lab's limit; 200 N for --criterion kappa)")  # fmt: skip
    p.add_argument("--tension-levels", type=integer(1, 100), default=4,
                   help="tension levels evenly up to --tension (default %(default)s)")  # fmt: skip
    p.add_argument(
        "--tests", type=integer(1, 10000), default=10, help="tests to choose (default %(default)s)"
    )
    p.add_argument("--criterion", choices=(*design.CRITERIA, "kappa"), default="minimax",
                   help="minimax: the worst joint's relative std (default); D, A, E; kappa: the paper's "
                        "selection (region poses in draw order, one test each)")  # fmt: skip
    p.add_argument("--no-bound", action="store_true", help="skip the convex relaxation and its bound")
    p.add_argument("--refine", type=integer(0, MAX_ROUNDS), default=0, metavar="ROUNDS",
                   help="minimax only: grow the pool around the design's poses and choose again, at most "
                        "ROUNDS times (docs/poses.md; 0.5-2.5 min per round; default %(default)s)")  # fmt: skip
    p.add_argument("--no-clearance", action="store_true",
                   help="skip the clearance check (docs/clearance.md; its link shells are the KR60's)")  # fmt: skip
    _noise_args(p)
    p.add_argument("--stiffness-prior", required=True, metavar="NAME|k1,..,k6",
                   help=f"your stiffness guess: a named prior ({', '.join(NAMED_PRIORS)}; the paper's Table 5 is "
                        "also this virtual lab's truth, so it flatters) or 6 values in N*mm/rad")  # fmt: skip
    p.set_defaults(func=_cmd_design)

    p = cmds.add_parser("next", help="the next tests after an identified dataset (its estimate as the prior)")
    p.add_argument("dataset", help="dataset directory (setup.json, tests.csv, clouds/)")
    p.add_argument("--tests", type=integer(1, 10000), default=5, help="tests to add (default %(default)s)")
    p.add_argument("--criterion", choices=minimax.RELAXED, default="minimax", help="default %(default)s")
    p.add_argument(
        "--method", choices=("fgls", "ols"), default="fgls", help="identification (default %(default)s)"
    )
    p.add_argument(
        "--n", type=integer(1, 10000), default=400, help="random poses of the pool (default %(default)s)"
    )
    p.add_argument("--seed", type=SEED, default=0, help="pose sampling seed (default %(default)s)")
    p.add_argument(
        "--tension", type=number(0, 1e5, "N"), default=None, help="top tension [N] (default: the lab's limit)"
    )
    p.add_argument("--tension-levels", type=integer(1, 100), default=4, help="default %(default)s")
    p.add_argument("--no-clearance", action="store_true", help="skip the clearance check (docs/clearance.md)")
    p.add_argument("--sigma-p", type=number(0, 1, "m", low_open=True), default=None,
                   help="displacement std [m] (default: from the identification's residuals)")  # fmt: skip
    p.add_argument("--sigma-r", type=number(0, 1, "rad", low_open=True), default=None,
                   help="rotation std [rad] (default: from the identification's residuals)")  # fmt: skip
    p.add_argument("--out", type=output_dir, help="directory for next.json and next_scenario.toml")
    p.set_defaults(func=_cmd_next)
