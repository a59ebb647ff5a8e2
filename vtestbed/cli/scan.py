"""``vtestbed scan``: scan the block unloaded and loaded, fit both clouds, compare with the truth."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import numpy as np

from ..errors import OutOfRangeError
from ..files import dumps
from ..robot_lab import lab_for_robot
from ..robots import DEFAULT_ROBOT
from .args import (
    SEED,
    add_load_arguments,
    add_pose_arguments,
    load_tension,
    number,
    output_dir,
    parse_numbers,
    runnable_pose,
)

DEFAULT_VIEW = "1,1,1"


def _cmd_scan(args) -> int:
    from .. import ply
    from ..researcher import cloud
    from ..researcher.kinematics import ArmKinematics
    from ..robots import load_robot
    from ..transforms import displacement, invert
    from ..world.rig import Rig
    from ..world.scan_noise import ScanNoise
    from ..world.scanner import Scanner

    robot = load_robot(args.robot)
    lab = lab_for_robot(robot)  # the robot's own lab: table, rings, tension and stand-off fit it
    tension = load_tension(args, lab)
    distance_m = lab.scanner_distance if args.distance_mm is None else args.distance_mm * 1e-3
    view = parse_numbers(args.view, "--view", 3, "direction in the block frame")
    if not np.linalg.norm(view) > 0:  # checked before --out is created: a refusal writes nothing
        raise OutOfRangeError(f"--view must be a non-zero direction in the block frame, got {args.view!r}")
    rig = Rig(robot, lab)
    q_cmd = runnable_pose(robot, lab, args)
    rig.command(q_cmd)
    rig.hook(args.hook, args.anchor)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    noise = ScanNoise.perfect() if args.noise_free else ScanNoise()
    rng = np.random.default_rng(args.seed)

    s0 = rig.solve()
    scanner = Scanner.place(
        rig.lab,
        s0.block_pose,
        distance_m=distance_m,
        view_direction_block=view,
        point_spacing_m=args.spacing_mm * 1e-3,
    )
    cloud0 = scanner.scan(rig.model, rig.data, rng, noise)
    s1 = rig.tighten(tension)
    cloud1 = scanner.scan(rig.model, rig.data, rng, noise)
    ply.write_ply(out / "unloaded.ply", cloud0)
    ply.write_ply(out / "loaded.ply", cloud1)

    # The researcher's side: nominal block pose from the kinematic model and the scanner's pose.
    kin = ArmKinematics(robot, rig.lab.block_in_flange)
    nominal = invert(scanner.pose_world) @ kin.tool_pose(q_cmd)
    params = cloud.FitParams(edge_m=rig.lab.block.edge)
    f0 = cloud.fit_block_frame(cloud0, nominal, params, rng)
    f1 = cloud.fit_block_frame(cloud1, f0, params, rng)
    measured = cloud.block_displacement(f0, f1, scanner.pose_world)
    true = displacement(s0.block_pose, s1.block_pose)
    to_s = invert(scanner.pose_world)
    result = {
        "units": "translation of the block reference point (frame B origin) [m], then rotation vector [rad]",
        "frame": "robot base",
        "displacement_measured": measured.tolist(),
        "displacement_true": true.tolist(),
        "displacement_error": (measured - true).tolist(),
        "displacement_measured_scanner": cloud.displacement_in_scanner(f0, f1).tolist(),
        "displacement_true_scanner": displacement(to_s @ s0.block_pose, to_s @ s1.block_pose).tolist(),
        "paper_T_O1_O0inv_measured": {
            "note": "paper Sec. 4.2: [dx, dy, dz] of T = O1 O0^-1 in the scanner frame (motion of the "
            "scanner origin, not of the block) [m], then gamma, beta, alpha about x, y, z [rad]",
            "values": cloud.paper_displacement(f0, f1).tolist(),
        },
        "pose": {"q_cmd_dh_deg": np.degrees(q_cmd).tolist(), "hook": args.hook, "anchor": args.anchor},
        "wire_tension_N": s1.wire_tension,
        "scanner": {
            "pose_world": scanner.pose_world.tolist(),
            "standoff_m": scanner.standoff_m,
            "area_m": list(scanner.area_m),
            "depth_m": scanner.depth_m,
            "point_spacing_m": scanner.point_spacing_m,
            "window": list(scanner.window) if scanner.window else None,
        },
        "noise": asdict(noise),
        "seed": args.seed,
        "clouds": {"unloaded": "unloaded.ply", "loaded": "loaded.ply", "points": [len(cloud0), len(cloud1)]},
        "fit": {
            name: {
                "pose_scanner": f.pose.tolist(),
                "points_per_face": f.counts.tolist(),
                "rms_residual_m": f.rms_residual_m.tolist(),
                "skew_rad": f.skew_rad,
                "outliers_removed": f.n_outliers_removed,
            }
            for name, f in (("unloaded", f0), ("loaded", f1))
        },
    }
    (out / "scan.json").write_text(dumps(result, indent=2))
    print(
        f"scanner {scanner.spec.name} at {distance_m * 1e3:g} mm, spacing {args.spacing_mm:g} mm, "
        f"{'noise-free' if args.noise_free else f'noise seed {args.seed}'}; clouds of {len(cloud0)} and "
        f"{len(cloud1)} points in {out}"
    )
    print(f"block displacement, robot base frame ({args.hook} -> {args.anchor}, {s1.wire_tension:.1f} N):")
    print(f"{'':8}{'measured':>14}{'true':>14}{'error':>12}")
    for i, name in enumerate(("dx [um]", "dy [um]", "dz [um]", "rx [urad]", "ry [urad]", "rz [urad]")):
        m, t = measured[i] * 1e6, true[i] * 1e6
        print(f"{name:10}{m:12.3f}{t:14.3f}{m - t:12.3f}")
    print(f"wrote {out / 'scan.json'}")
    return 0


def register(sub) -> None:
    p = sub.add_parser("scan", help="scan the block unloaded and loaded; measured vs true displacement")
    p.add_argument(
        "--out", type=output_dir, required=True, help="output folder for the PLY clouds and scan.json"
    )
    p.add_argument("--robot", default=DEFAULT_ROBOT)
    add_pose_arguments(p)
    add_load_arguments(p)
    p.add_argument(
        "--distance-mm",
        type=number(0, 1e4, "mm", low_open=True),
        default=None,
        help="scanner to block centre (default: the robot's lab's stand-off, docs/lab.md: 600 mm for the KR60-3)",
    )
    p.add_argument(
        "--view",
        default=DEFAULT_VIEW,
        help="direction block centre -> scanner in the block frame (default %(default)s)",
    )
    p.add_argument(
        "--spacing-mm",
        type=number(0.02, 5, "mm"),
        default=0.5,
        help="point spacing at the block (default %(default)s)",
    )
    p.add_argument("--seed", type=SEED, default=0, help="noise seed (default %(default)s)")
    p.add_argument(
        "--noise-free", action="store_true", help="a perfect scanner (no noise, outliers or drift)"
    )
    p.set_defaults(func=_cmd_scan)
