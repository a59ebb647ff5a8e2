"""``vtestbed poses ...``: the arm-wrist criterion, its maps, optimum, joint influence, test regions
and the experiment design. Every command prints JSON; ``--out DIR`` also writes files there.
Angles on the command line are DH angles in degrees (``--controller-deg`` for KUKA A1..A6).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..design import influence, kappa, regions
from ..design.plots import plot_cartesian, plot_influence, plot_joint_plane
from ..errors import OutOfRangeError, ScenarioError, check_range
from ..files import dumps, read_json
from ..robot_lab import lab_for_robot
from ..robots import DEFAULT_ROBOT, load_robot
from .args import NEGATIVE_HINT, SEED, integer, number, output_dir, parse_angles_deg, parse_numbers


def _point(text: str):
    if text in kappa.POINTS:
        return text
    return kappa.reference_offset(parse_numbers(text, "--point", 3, "m"))


def _pose(robot, args, default=None):
    if getattr(args, "controller_deg", None):
        return robot.controller_to_dh(parse_angles_deg(args.controller_deg, "--controller-deg", robot.dof))
    if getattr(args, "q_deg", None):
        return parse_angles_deg(args.q_deg, "--q-deg", robot.dof)
    return default


def _emit(args, data: dict, filename: str | None = None) -> None:
    text = dumps(data, indent=1)
    if filename and getattr(args, "out", None):
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / filename).write_text(text + "\n")
    print(text)


def _optimum(robot, args) -> kappa.Optimum:
    j6 = robot.joints[-1]
    q6 = np.radians(check_range("--q6-deg", args.q6_deg, np.degrees(j6.lower), np.degrees(j6.upper), "deg"))
    return kappa.optimize(robot, point=_point(args.point), seed=args.seed, q6=q6)


def _read_poses(path: str, robot) -> np.ndarray:
    """The DH poses [rad] of a poses.json (from 'poses regions'): ``q_deg``, rows of dof finite numbers."""
    data = read_json(path, "poses file (from 'vtestbed poses regions')", ScenarioError)
    rows = data.get("q_deg")
    ok = (
        isinstance(rows, list)
        and len(rows) > 0
        and all(isinstance(r, list) and len(r) == robot.dof for r in rows)
        and all(isinstance(v, int | float) and not isinstance(v, bool) for r in rows for v in r)
    )
    q = np.asarray(rows, dtype=float) if ok else None
    if q is None or not np.all(np.isfinite(q)):
        raise ScenarioError(
            f"{path}: q_deg must be a non-empty list of poses, each {robot.dof} finite DH angles in degrees, "
            f"got {str(rows)[:80]}"
        )
    for i, row in enumerate(np.radians(q)):  # name the file and the pose, not a bare "pose"
        robot.check_pose(row, field=f"{path}: q_deg[{i}]")
    return np.radians(q)


def _constraints(args, robot) -> regions.PoseConstraints:
    """The block zone of the options, defaulting to the robot's lab's (:func:`vtestbed.robot_lab.lab_for_robot`)."""
    zone = lab_for_robot(robot).zone
    if args.box is None:
        box = zone.box
    else:
        box = parse_numbers(args.box, "--box", 6, "m") if args.box else None
        if box is not None and not np.all(box[:3] < box[3:]):
            raise OutOfRangeError(
                f"--box must be x_min,y_min,z_min,x_max,y_max,z_max [m] with each min below its max,"
                f" got {args.box!r}"
            )
    min_height = zone.min_height if args.min_height is None else args.min_height
    return regions.PoseConstraints(
        point="block", min_height=min_height, box_min=None if box is None else tuple(box[:3]),
        box_max=None if box is None else tuple(box[3:]),
    )  # fmt: skip


def _cmd_criterion(args) -> int:
    robot = load_robot(args.robot)
    q = _pose(robot, args)
    if q is None:
        raise OutOfRangeError("give a pose: --q-deg a,b,c,d,e,f (DH) or --controller-deg (KUKA A1..A6)")
    value = kappa.criterion(robot, q, point=_point(args.point), check_limits=not args.no_limits)
    _emit(args, value.to_dict() | {"q_controller_deg": np.degrees(robot.dh_to_controller(q)).tolist()})
    return 0


def _paper_comparison(robot, point) -> dict:
    out = {"paper_q_deg_as_printed": list(kappa.PAPER_OPTIMUM_DEG)}
    for name, as_ctrl in (("as_controller", True), ("as_dh", False)):
        q = kappa.paper_optimum(robot, as_controller=as_ctrl)
        value = kappa.criterion(robot, q, point=point, check_limits=False)
        f = lambda x, q=q: kappa.inv_kappa_batch(robot, np.r_[q[0], x, q[5]][None], point)[0]  # noqa: E731
        grad, curv = kappa.finite_difference(f, q[1:5])
        out[name] = {"q_dh_deg": np.degrees(q).tolist(), "inv_kappa": value.inv_kappa,
                     "gradient_per_rad": grad.tolist(), "curvature_per_deg2": (curv * influence.DEG2).tolist()}  # fmt: skip
    return out


def _cmd_optimize(args) -> int:
    robot = load_robot(args.robot)
    opt = _optimum(robot, args)
    data = opt.to_dict() | {"q_controller_deg": np.degrees(robot.dh_to_controller(opt.q)).tolist()}
    data["wrist"] = regions.wrist_report(robot, opt.q, _point(args.point))
    if robot.name == DEFAULT_ROBOT:  # the paper's pose is a KR60-3 pose; elsewhere it means nothing
        data["paper"] = _paper_comparison(robot, _point(args.point))
    _emit(args, data, "optimum.json")
    return 0


def _cmd_maps(args) -> int:
    robot = load_robot(args.robot)
    point = _point(args.point)
    q, label = _pose(robot, args, default=None), "given pose"
    if q is None:
        q, label = _optimum(robot, args).q, "optimum"
    pmap = regions.joint_plane_map(robot, q, point, step_deg=args.step_deg)
    found = regions.find_regions(pmap, threshold=args.threshold)
    cmap = regions.cartesian_map(robot, q, point, step_deg=args.step_deg / 2)
    data = {"q_fixed_deg": np.degrees(q).tolist(), "point": pmap.point, "max_inv_kappa": float(pmap.values.max()),
            "regions": [r.to_dict(pmap) for r in found]}  # fmt: skip
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        marks = [(label, q, "w*")]
        if robot.name == DEFAULT_ROBOT:
            marks.append(("paper's optimum (as controller angles)", kappa.paper_optimum(robot), "ro"))
        plot_joint_plane(pmap, found, out / "joint_plane.png", marks)
        plot_cartesian(cmap, out / "cartesian.png")
        data["files"] = [str(out / "joint_plane.png"), str(out / "cartesian.png")]
    _emit(args, data, "maps.json")
    return 0


def _cmd_influence(args) -> int:
    robot = load_robot(args.robot)
    if args.point == "all":
        rows = influence.reference_point_study(robot, seed=args.seed, method=args.method)
        _emit(args, {"reference_points": rows}, "influence.json")
        return 0
    point = _point(args.point)
    q = _pose(robot, args) if (args.q_deg or args.controller_deg) else _optimum(robot, args).q
    inf = influence.joint_influence(robot, q, point=point, method=args.method)
    if args.out:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        plot_influence(inf, Path(args.out) / "influence.png")
    _emit(args, inf.to_dict(), "influence.json")
    return 0


def _regions_and_poses(robot, args):
    q = _optimum(robot, args).q
    pmap = regions.joint_plane_map(robot, q, _point(args.point), step_deg=args.step_deg)
    found = regions.restrict(
        regions.find_regions(pmap, threshold=args.threshold), pmap, robot, _constraints(args, robot)
    )
    select = args.select.split(",") if args.select else None
    rng = np.random.default_rng(args.seed)
    sample = regions.sample_poses(robot, pmap, found, args.n, rng, select=select, constraints=_constraints(args, robot),
                                  wrist_jitter_deg=args.wrist_jitter_deg, threshold=args.threshold)  # fmt: skip
    return pmap, found, sample


def _cmd_regions(args) -> int:
    robot = load_robot(args.robot)
    pmap, found, sample = _regions_and_poses(robot, args)
    data = {"constraints": vars(_constraints(args, robot)), "regions": [r.to_dict(pmap) for r in found],
            "poses": sample.to_dict(), "wrist": regions.wrist_report(robot, sample.q, pmap.point)}  # fmt: skip
    if args.out:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        marks = [(f"{len(sample.q)} sampled poses", sample.q, "w.")]
        plot_joint_plane(pmap, found, Path(args.out) / "regions.png", marks)
        (Path(args.out) / "poses.json").write_text(dumps(sample.to_dict(), indent=1) + "\n")
    _emit(args, data, "regions.json")
    return 0


def register(sub) -> None:
    group = sub.add_parser("poses", help="pose selection away from singularities and experiment design")
    cmds = group.add_subparsers(dest="poses_command", required=True)

    def common(p, pose=False, out=True):
        p.add_argument("--robot", default=DEFAULT_ROBOT)
        p.add_argument(
            "--point", default="wrist", help="wrist | flange | block | x,y,z offset in the flange [m]"
        )
        p.add_argument("--seed", type=SEED, default=0, help="optimiser/sampling seed (default %(default)s)")
        p.add_argument(
            "--q6-deg",
            type=number(-360, 360, "deg"),
            default=45.0,
            help="joint 6 for the optimum (default 45)",
        )
        if pose:
            angles = p.add_mutually_exclusive_group()  # one pose: two would silently drop one
            angles.add_argument("--q-deg", help=f"DH joint angles in degrees ({NEGATIVE_HINT})")
            angles.add_argument("--controller-deg", help="KUKA controller angles A1..A6 in degrees")
        if out:
            p.add_argument("--out", type=output_dir, help="directory for JSON and PNG files")

    def lab_args(p):
        p.add_argument(
            "--step-deg",
            type=number(0.05, 30, "deg"),
            default=1.0,
            help="joint 2-3 grid step (default %(default)s)",
        )
        p.add_argument(
            "--threshold", type=number(0, 1), default=0.7, help="region threshold (default %(default)s)"
        )
        p.add_argument(
            "--min-height",
            type=number(-10, 10, "m"),
            help="lowest block z [m] (default: the robot's lab's block zone, 0.8 m for the KR60-3)",
        )
        p.add_argument(
            "--box",
            help="lab box xmin,ymin,zmin,xmax,ymax,zmax [m] ('' for none; default: the robot's lab's block zone)",
        )
        p.add_argument("--select", help="regions to draw from, e.g. Z1,Z4 (default: all usable)")
        p.add_argument("--n", type=integer(1, 10000), default=10, help="poses to draw (default %(default)s)")
        p.add_argument(
            "--wrist-jitter-deg",
            type=number(0, 180, "deg"),
            default=30.0,
            help="joints 4, 5 spread (default 30)",
        )

    p = cmds.add_parser("criterion", help="the criterion at one pose (JSON)")
    common(p, pose=True, out=False)
    p.add_argument("--no-limits", action="store_true", help="allow a pose outside the joint limits")
    p.set_defaults(func=_cmd_criterion)

    p = cmds.add_parser("optimize", help="maximise the criterion over joints 2-5 (writes optimum.json)")
    common(p)
    p.set_defaults(func=_cmd_optimize)

    p = cmds.add_parser("maps", help="joint 2-3 and Cartesian maps (PNG) and the regions")
    common(p, pose=True)
    p.add_argument(
        "--step-deg",
        type=number(0.05, 30, "deg"),
        default=0.5,
        help="joint 2-3 grid step (default %(default)s)",
    )
    p.add_argument(
        "--threshold", type=number(0, 1), default=0.7, help="region threshold (default %(default)s)"
    )
    p.set_defaults(func=_cmd_maps)

    p = cmds.add_parser("influence", help="joint influence (curvature at the optimum) and ranking")
    common(p, pose=True)
    p.add_argument("--method", choices=influence.METHODS, default="fd")
    p.set_defaults(func=_cmd_influence)
    p.epilog = "--point all compares wrist, flange and block against the paper's Table 2"

    p = cmds.add_parser("regions", help="high-criterion regions, lab constraints, sampled test poses")
    common(p)
    lab_args(p)
    p.set_defaults(func=_cmd_regions)

    from .poses_design import add_design_parsers  # the experiment-design commands: design, next

    add_design_parsers(cmds, common, lab_args)
