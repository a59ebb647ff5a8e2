"""``vtestbed robot``, ``vtestbed load`` and ``vtestbed models``: the truth world at a glance."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np

from ..files import dumps
from ..robots import DEFAULT_ROBOT, available_robots, load_robot
from ..transforms import displacement
from .args import add_load_arguments, add_pose_arguments, load_tension, runnable_pose


def _cmd_robot(args) -> int:
    from ..world.truth import load_truth  # the world's side of the robot: its true stiffness

    robot = load_robot(args.robot)
    k_true = load_truth(robot.name).stiffness_true
    print(f"{robot.display_name} ({robot.name}), {robot.dof} joints, total mass {robot.total_mass:.0f} kg")
    print(
        f"{'joint':8}{'alpha[deg]':>11}{'a[mm]':>8}{'d[mm]':>8}{'limits DH [deg]':>20}{'k_true [N*mm/rad]':>20}"
    )
    for j, k in zip(robot.joints, k_true):
        lim = f"[{np.degrees(j.lower):.0f}, {np.degrees(j.upper):.0f}]"
        print(
            f"{j.name:8}{np.degrees(j.alpha_prev):11.0f}{j.a_prev * 1e3:8.0f}{j.d * 1e3:8.0f}"
            f"{lim:>20}{k * 1e3:20.4e}"
        )
    print(f"robots available: {', '.join(available_robots())}")
    return 0


def _install(imported, directory: Path, force: bool) -> list[Path]:
    """Write ``models/<name>/`` whole or not at all (docs/robots.md): the five files go to a dot
    folder beside it (same file system, hidden from ``vtestbed robot``), are read back with the
    checks every load makes and compiled by MuJoCo, and only then moved into place. A refused
    import leaves nothing; with ``--force`` the files replace the old ones one by one (each
    ``os.replace`` is atomic), and other files a user keeps in the folder stay."""
    from ..errors import DescriptionError
    from ..robot_import import FILES, write_folder
    from ..robot_lab import lab_for_robot
    from ..robots import robot_from_file
    from ..world.mjcf import build_scene_spec, write_model_files
    from ..world.truth import TRUTH_FILE_NAME, truth_from_file

    if (directory / "robot.toml").exists() and not force:
        raise DescriptionError(f"{directory / 'robot.toml'} exists already; pass --force to overwrite it")
    directory.parent.mkdir(parents=True, exist_ok=True)
    # mkdir, not mkdtemp: the folder keeps the umask's mode (mkdtemp's 0700 would survive the rename)
    staging = directory.parent / f".{directory.name}.import-{os.getpid()}"
    shutil.rmtree(staging, ignore_errors=True)  # a crashed import of this pid's
    staging.mkdir()
    try:
        write_folder(imported, staging)
        robot = robot_from_file(staging / "robot.toml")
        truth = truth_from_file(staging / TRUTH_FILE_NAME, robot)
        try:  # anything MuJoCo refuses (the checks above should leave nothing) is a refused import
            build_scene_spec(robot, truth, lab_for_robot(robot)).compile()
        except ValueError as exc:
            raise DescriptionError(f"the imported robot does not compile in MuJoCo: {exc}") from None
        names = [*FILES, *(p.name for p in write_model_files(robot, staging, truth))]
        if not directory.exists():
            staging.rename(directory)  # atomic: the folder appears complete
        else:
            for name in names:
                os.replace(staging / name, directory / name)
        return [directory / name for name in names]
    finally:
        shutil.rmtree(staging, ignore_errors=True)  # after a rename there is nothing left to remove


def _cmd_import(args) -> int:
    from ..errors import DescriptionError
    from ..robot_import import check_name, import_urdf
    from ..robots import MODELS_DIR
    from ..urdf import read_urdf
    from ..world.truth import load_truth

    name = check_name(args.name)
    stiffness = None
    if args.stiffness is not None:
        try:
            stiffness = [float(v) for v in args.stiffness.split(",")]
        except ValueError:
            raise DescriptionError(
                f"--stiffness-Nm-per-rad {args.stiffness!r} must be 6 comma-separated numbers [N*m/rad]"
            ) from None
    imported = import_urdf(read_urdf(args.urdf), name, args.base, args.tip, stiffness, args.source or "",
                           args.rated_payload_kg)  # fmt: skip
    written = _install(imported, MODELS_DIR / name, args.force)
    load_robot.cache_clear()  # a re-import replaces a description this process may have read
    load_truth.cache_clear()
    print(f"imported {', '.join(imported.chain)} as {name} (DH form exact to {imported.max_error:.1e})")
    for path in written:
        print(f"wrote {path}")
    return 0


def _cmd_load(args) -> int:
    from ..robot_lab import lab_for_robot
    from ..world.clearance import describe_test, ground_clearance
    from ..world.rig import Rig

    robot = load_robot(args.robot)
    lab = lab_for_robot(robot)  # the robot's own lab: table, rings and tension limit fit it
    tension = load_tension(args, lab)
    q = runnable_pose(robot, lab, args)
    rig = Rig(robot, lab)
    rig.command(q)
    rig.hook(args.hook, args.anchor)
    unloaded = rig.solve()
    loaded = rig.tighten(tension)
    # an arm in the table or the floor: numbers of a pose no lab can hold (the wire's and the
    # scanner's clearance, which `simulate` checks too, belong to a test, not to this probe of a load)
    ground_clearance(rig).enforce(describe_test(q, args.hook, args.anchor), "raise")
    disp = displacement(unloaded.block_pose, loaded.block_pose)
    result = {
        "q_cmd_deg": np.degrees(loaded.q_cmd).tolist(),
        "deflection_gravity_urad": (unloaded.deflection * 1e6).tolist(),
        "deflection_wire_urad": ((loaded.q - unloaded.q) * 1e6).tolist(),
        "wire_tension_N": loaded.wire_tension,
        "sensor_wrench_unloaded": unloaded.sensor_wrench.tolist(),
        "sensor_wrench_loaded": loaded.sensor_wrench.tolist(),
        "block_displacement_mm_mrad": (disp * 1e3).tolist(),
    }
    if args.json:
        print(dumps(result, indent=2))
        return 0
    print(f"pose (DH) [deg]: {np.round(result['q_cmd_deg'], 3).tolist()}; wire {args.hook} -> {args.anchor}")
    print(f"wire tension {loaded.wire_tension:.3f} N; equilibrium residual {loaded.residual:.1e} N*m")
    print(f"{'joint':8}{'gravity defl [urad]':>22}{'wire defl [urad]':>20}")
    for name, g, w in zip(
        robot.joint_names, result["deflection_gravity_urad"], result["deflection_wire_urad"]
    ):
        print(f"{name:8}{g:22.3f}{w:20.3f}")
    print("F/T loaded   [N, N*m]:", np.array2string(loaded.sensor_wrench, precision=3))
    print(
        "block displacement, base frame: translation [mm]",
        np.round(disp[:3] * 1e3, 5).tolist(),
        "rotation [mrad]",
        np.round(disp[3:] * 1e3, 5).tolist(),
    )
    return 0


def _cmd_models(args) -> int:
    from ..world.mjcf import write_model_files

    for path in write_model_files(load_robot(args.robot)):
        print(f"wrote {path}")
    return 0


def register(sub) -> None:
    p = sub.add_parser("robot", help="summary of a robot description; 'robot import' brings a URDF")
    p.add_argument("--robot", default=DEFAULT_ROBOT)
    p.set_defaults(func=_cmd_robot)
    actions = p.add_subparsers(dest="robot_action")
    imp = actions.add_parser(
        "import", help="build models/NAME (description, truth, MJCF, README) from a URDF's 6R chain"
    )
    imp.add_argument("urdf", help="the URDF file")
    imp.add_argument("--name", required=True, help="the robot's name, its folder models/NAME")
    imp.add_argument("--base", help="the base link (default: the URDF's root link)")
    imp.add_argument("--tip", help="the flange link (default: the child of the sixth revolute joint)")
    imp.add_argument(
        "--stiffness-Nm-per-rad",
        dest="stiffness",
        metavar="K1,...,K6",
        help="true joint stiffness [N*m/rad] (default: rated torque / 2.5 mrad, docs/robots.md)",
    )
    imp.add_argument("--source", help="where the URDF came from, for the README")
    imp.add_argument("--rated-payload-kg", type=float, metavar="KG",
                     help="the maker's rated payload [kg]: caps the wire tension (default: no cap from the robot)")  # fmt: skip
    imp.add_argument("--force", action="store_true", help="overwrite an existing models/NAME")
    imp.set_defaults(func=_cmd_import)

    p = sub.add_parser("load", help="joint deflections and block displacement at a pose and a wire tension")
    p.add_argument("--robot", default=DEFAULT_ROBOT)
    add_pose_arguments(p)
    add_load_arguments(p)
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=_cmd_load)

    p = sub.add_parser("models", help="regenerate the committed MJCF files from the description")
    p.add_argument("--robot", default=DEFAULT_ROBOT)
    p.set_defaults(func=_cmd_models)
