"""``vtestbed poses ...``: the arm-wrist criterion, its maps, optimum, joint influence, test regions
and the experiment design. Every command prints JSON; ``--out DIR`` also writes files there.
Angles on the command line are DH angles in degrees (``--controller-deg`` for KUKA A1..A6).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..design import criterion as poses
from ..design import influence, regions
from ..design import optimal as design
from ..errors import OutOfRangeError
from ..robots import load_robot
from .robot import parse_angles_deg, parse_numbers

DEFAULT_BOX = "0.3,-1.0,0.0,2.3,1.0,2.2"  # m: xmin,ymin,zmin,xmax,ymax,zmax, in front of the robot


def _point(text: str):
    if text in poses.POINTS:
        return text
    return poses.reference_offset(parse_numbers(text, "--point", 3, "m"))


def _pose(robot, args, default=None):
    if getattr(args, "controller_deg", None):
        return robot.controller_to_dh(parse_angles_deg(args.controller_deg, "--controller-deg", robot.dof))
    if getattr(args, "q_deg", None):
        return parse_angles_deg(args.q_deg, "--q-deg", robot.dof)
    return default


def _emit(args, data: dict, filename: str | None = None) -> None:
    text = json.dumps(data, indent=1)
    if filename and getattr(args, "out", None):
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / filename).write_text(text + "\n")
    print(text)


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _optimum(robot, args) -> poses.Optimum:
    return poses.optimize(robot, point=_point(args.point), seed=args.seed, q6=np.radians(args.q6_deg))


def _constraints(args) -> regions.PoseConstraints:
    box = parse_numbers(args.box, "--box", 6, "m") if args.box else None
    return regions.PoseConstraints(
        point="block", min_height=args.min_height, box_min=None if box is None else tuple(box[:3]),
        box_max=None if box is None else tuple(box[3:]),
    )  # fmt: skip


def plot_joint_plane(pmap, found, path, marks=()) -> None:
    """Contour of the criterion over theta_2 (x) and theta_3 (y) with the regions outlined."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 6.5))
    g2, g3 = np.degrees(pmap.theta2), np.degrees(pmap.theta3)
    cs = ax.contourf(g2, g3, pmap.values.T, levels=np.linspace(0, 1, 21), cmap="viridis")
    fig.colorbar(cs, ax=ax, label=r"$\kappa(J_{AW})^{-1}$")
    for r in found:
        colour = "white" if r.excluded is None else "red"
        if r.removed is not None and r.removed.any():
            whole = (r.mask | r.removed).T.astype(float)
            ax.contour(g2, g3, whole, levels=[0.5], colors="red", linewidths=1.0, linestyles="dashed")
        if r.mask.any():
            ax.contour(g2, g3, r.mask.T.astype(float), levels=[0.5], colors=colour, linewidths=1.2)
        label = r.name if r.excluded is None else f"{r.name} (excluded)"
        cells = r.mask if r.excluded is None or r.removed is None else r.mask | r.removed
        where = np.degrees(r.peak)
        if cells.any():
            i2, i3 = np.nonzero(cells)
            where = (g2[i2].mean(), g3[i3].mean())
        ax.annotate(label, where, color=colour, fontsize=11, ha="center", va="center", weight="bold")
    for name, q, style in marks:
        q = np.atleast_2d(q)
        ax.plot(np.degrees(q[:, 1]), np.degrees(q[:, 2]), style, label=name, ms=8, mec="k", ls="none")
    if marks:
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=len(marks), fontsize=8)
    ax.set_xlabel(r"$\theta_2$ (DH) [deg]")
    ax.set_ylabel(r"$\theta_3$ (DH) [deg]")
    q = np.degrees(pmap.q_fixed)
    ax.set_title(
        f"criterion at {pmap.point}; theta1,4,5,6 = {q[0]:.0f}, {q[3]:.0f}, {q[4]:.0f}, {q[5]:.0f} deg"
    )
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_cartesian(cmap, path, lab=None) -> None:
    """Best criterion per (x, z) bin of the reference point, with floor and table."""
    from ..lab import LabSetup

    plt = _pyplot()
    lab = lab or LabSetup()
    fig, ax = plt.subplots(figsize=(7.5, 6))
    x = (cmap.x_edges[:-1] + cmap.x_edges[1:]) / 2
    z = (cmap.z_edges[:-1] + cmap.z_edges[1:]) / 2
    values = np.ma.masked_invalid(cmap.values.T)
    cs = ax.contourf(x, z, values, levels=np.linspace(0, 1, 21), cmap="viridis")
    fig.colorbar(cs, ax=ax, label=r"best $\kappa(J_{AW})^{-1}$ reaching the bin")
    t = lab.table
    ax.plot(
        [t.center[0] - t.size[0] / 2, t.center[0] + t.size[0] / 2], [t.height] * 2, "k-", lw=3, label="table"
    )
    ax.axhspan(min(cmap.z_edges[0], 0.0), 0.0, color="0.6", alpha=0.6, label="below the floor")
    ax.plot([0, 0], [0, 0.815], "k--", lw=1, label="axis 1")
    ax.set_aspect("equal")
    ax.set_xlabel("x (base) [m]")
    ax.set_ylabel("z (base) [m]")
    name = "wrist centre" if cmap.point == "wrist" else cmap.point
    ax.set_title(f"{name} position (x, z); theta1 = 0, theta6 = 45 deg")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_influence(inf, path) -> None:
    """Curves along each joint (paper Fig. 3) and shifted to a common maximum (Fig. 4)."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    for c in inf.curves:
        label = f"joint {c.joint}: {c.curvature(inf.method):.3g} /deg$^2$"
        axes[0].plot(np.degrees(c.angles), c.values, label=label)
        axes[1].plot(np.degrees(c.angles - c.at), c.values, label=f"joint {c.joint}")
    axes[0].set_xlabel("joint angle (DH) [deg]")
    axes[1].set_xlabel("joint angle - optimum [deg]")
    axes[1].set_xlim(-90, 90)
    for ax in axes:
        ax.set_ylabel(r"$\kappa(J_{AW})^{-1}$")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    axes[0].set_title(f"influence at {inf.point}; ranking {' > '.join(map(str, inf.ranking))}")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _cmd_criterion(args) -> int:
    robot = load_robot(args.robot)
    q = _pose(robot, args)
    if q is None:
        raise OutOfRangeError("give a pose: --q-deg a,b,c,d,e,f (DH) or --controller-deg (KUKA A1..A6)")
    value = poses.criterion(robot, q, point=_point(args.point), check_limits=not args.no_limits)
    _emit(args, value.to_dict() | {"q_controller_deg": np.degrees(robot.dh_to_controller(q)).tolist()})
    return 0


def _paper_comparison(robot, point) -> dict:
    out = {"paper_q_deg_as_printed": list(poses.PAPER_OPTIMUM_DEG)}
    for name, as_ctrl in (("as_controller", True), ("as_dh", False)):
        q = poses.paper_optimum(robot, as_controller=as_ctrl)
        value = poses.criterion(robot, q, point=point, check_limits=False)
        f = lambda x, q=q: poses.inv_kappa_batch(robot, np.r_[q[0], x, q[5]][None], point)[0]  # noqa: E731
        grad, curv = poses.finite_difference(f, q[1:5])
        out[name] = {"q_dh_deg": np.degrees(q).tolist(), "inv_kappa": value.inv_kappa,
                     "gradient_per_rad": grad.tolist(), "curvature_per_deg2": (curv * influence.DEG2).tolist()}  # fmt: skip
    return out


def _cmd_optimize(args) -> int:
    robot = load_robot(args.robot)
    opt = _optimum(robot, args)
    data = opt.to_dict() | {"q_controller_deg": np.degrees(robot.dh_to_controller(opt.q)).tolist()}
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
        marks = [
            (label, q, "w*"),
            ("paper's optimum (as controller angles)", poses.paper_optimum(robot), "ro"),
        ]
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
        regions.find_regions(pmap, threshold=args.threshold), pmap, robot, _constraints(args)
    )
    select = args.select.split(",") if args.select else None
    rng = np.random.default_rng(args.seed)
    sample = regions.sample_poses(robot, pmap, found, args.n, rng, select=select, constraints=_constraints(args),
                                  wrist_jitter_deg=args.wrist_jitter_deg, threshold=args.threshold)  # fmt: skip
    return pmap, found, sample


def _cmd_regions(args) -> int:
    robot = load_robot(args.robot)
    pmap, found, sample = _regions_and_poses(robot, args)
    data = {"constraints": vars(_constraints(args)), "regions": [r.to_dict(pmap) for r in found],
            "poses": sample.to_dict()}  # fmt: skip
    if args.out:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        marks = [(f"{len(sample.q)} sampled poses", sample.q, "w.")]
        plot_joint_plane(pmap, found, Path(args.out) / "regions.png", marks)
        (Path(args.out) / "poses.json").write_text(json.dumps(sample.to_dict(), indent=1) + "\n")
    _emit(args, data, "regions.json")
    return 0


def _cmd_design(args) -> int:
    robot = load_robot(args.robot)
    if args.poses:
        q = np.radians(np.asarray(json.loads(Path(args.poses).read_text())["q_deg"], dtype=float))
    else:
        q = _regions_and_poses(robot, args)[2].q
    hooks = args.hooks.split(",") if args.hooks else None
    anchors = args.anchors.split(",") if args.anchors else None
    cands = design.candidate_tests(robot, q, hooks, anchors, tension=args.tension)
    prior = parse_numbers(args.stiffness_prior_nmm, "--stiffness-prior-nmm", 6, "N*mm/rad") / 1e3
    sel = design.select_tests(cands, args.tests, prior, criterion=args.criterion, method=args.method,
                              sigma_p=args.sigma_p, sigma_r=args.sigma_r)  # fmt: skip
    data = {"candidates": len(cands), "sigma_p_m": args.sigma_p, "sigma_r_rad": args.sigma_r,
            "stiffness_prior_Nmm_per_rad": (prior * 1e3).tolist(), "selection": sel.to_dict(),
            "tests": [cands[i].to_dict() for i in sel.indices]}  # fmt: skip
    if args.out:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        header = f"# {args.tests} tests chosen by 'vtestbed poses design' ({args.criterion}-optimal, {args.method})\n"
        toml = header + design.scenario_toml([cands[i] for i in sel.indices])
        (Path(args.out) / "design_scenario.toml").write_text(toml)
    _emit(args, data, "design.json")
    return 0


def register(sub) -> None:
    group = sub.add_parser("poses", help="pose selection away from singularities and experiment design")
    cmds = group.add_subparsers(dest="poses_command", required=True)

    def common(p, pose=False, out=True):
        p.add_argument("--robot", default="kuka_kr60_3")
        p.add_argument(
            "--point", default="wrist", help="wrist | flange | block | x,y,z offset in the flange [m]"
        )
        p.add_argument("--seed", type=int, default=0, help="optimiser/sampling seed (default %(default)s)")
        p.add_argument("--q6-deg", type=float, default=45.0, help="joint 6 for the optimum (default 45)")
        if pose:
            p.add_argument("--q-deg", help="DH joint angles in degrees")
            p.add_argument("--controller-deg", help="KUKA controller angles A1..A6 in degrees")
        if out:
            p.add_argument("--out", help="directory for JSON and PNG files")

    def lab_args(p):
        p.add_argument(
            "--step-deg", type=float, default=1.0, help="joint 2-3 grid step (default %(default)s)"
        )
        p.add_argument("--threshold", type=float, default=0.7, help="region threshold (default %(default)s)")
        p.add_argument(
            "--min-height", type=float, default=0.8, help="lowest block z [m] (default %(default)s)"
        )
        p.add_argument(
            "--box", default=DEFAULT_BOX, help="lab box xmin,ymin,zmin,xmax,ymax,zmax [m] ('' for none)"
        )
        p.add_argument("--select", help="regions to draw from, e.g. Z1,Z4 (default: all usable)")
        p.add_argument("--n", type=int, default=10, help="poses to draw (default %(default)s)")
        p.add_argument("--wrist-jitter-deg", type=float, default=30.0, help="joints 4, 5 spread (default 30)")

    p = cmds.add_parser("criterion", help="the criterion at one pose (JSON)")
    common(p, pose=True, out=False)
    p.add_argument("--no-limits", action="store_true", help="allow a pose outside the joint limits")
    p.set_defaults(func=_cmd_criterion)

    p = cmds.add_parser("optimize", help="maximise the criterion over joints 2-5 (writes optimum.json)")
    common(p)
    p.set_defaults(func=_cmd_optimize)

    p = cmds.add_parser("maps", help="joint 2-3 and Cartesian maps (PNG) and the regions")
    common(p, pose=True)
    p.add_argument("--step-deg", type=float, default=0.5, help="joint 2-3 grid step (default %(default)s)")
    p.add_argument("--threshold", type=float, default=0.7, help="region threshold (default %(default)s)")
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

    p = cmds.add_parser("design", help="choose tests by D/A/E-optimality; predicted std of each k")
    common(p)
    lab_args(p)
    p.add_argument(
        "--poses", help="poses.json (from 'poses regions'); default: draw --n poses from the regions"
    )
    p.add_argument("--hooks", help="comma-separated hooks (default all)")
    p.add_argument("--anchors", help="comma-separated rings (default all)")
    p.add_argument("--tension", type=float, default=200.0, help="wire tension [N] (default %(default)s)")
    p.add_argument("--tests", type=int, default=10, help="tests to choose (default %(default)s)")
    p.add_argument("--criterion", choices=design.CRITERIA, default="D")
    p.add_argument("--method", choices=design.METHODS, default="exchange")
    p.add_argument("--sigma-p", type=float, default=design.SIGMA_P, help="displacement std [m]")
    p.add_argument("--sigma-r", type=float, default=design.SIGMA_R, help="rotation std [rad]")
    p.add_argument("--stiffness-prior-nmm", default=",".join(f"{k:g}" for k in design.PAPER_STIFFNESS_NMM),
                   help="prior stiffness [N*mm/rad] (default: paper Table 5 = this lab's truth; flattering)")  # fmt: skip
    p.set_defaults(func=_cmd_design)
