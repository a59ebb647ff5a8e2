"""``vtestbed diagnose DATASET``: detect, name and add what the paper's model misses (researcher side)."""

from __future__ import annotations

from pathlib import Path

from ..files import dumps
from ..researcher.block_size import SCALE_TOLERANCE_PPM, SCALE_TOLERANCE_RANGE_PPM
from .args import number, output_dir


def _cmd_diagnose(args) -> int:
    from ..errors import OutOfRangeError, require_level
    from ..researcher.discrepancy import diagnose, markdown
    from ..robots import load_robot

    names = () if (args.candidates or "").strip() == "none" else args.candidates  # none: the detection alone
    if names and "none" in [n.strip() for n in names.split(",")]:
        raise OutOfRangeError(
            f"--candidates {names!r}: 'none' (the detection test alone) stands alone; give it by itself, or "
            "candidate names without it"
        )
    require_level(args.alpha, "--alpha")
    # the library's defaults where the option is not given
    rank = {} if args.rank is None else {"rank_by": args.rank}
    statics = {} if args.statics is None else {"statics": args.statics}
    report = diagnose(args.dataset, alpha=args.alpha, names=names, out=args.out,
                      scale_tolerance_ppm=args.scale_tolerance, **rank, **statics)  # fmt: skip
    html = None
    if args.out:
        from ..reports import write_report

        html = write_report(args.out)
    if args.json:
        print(dumps(report, indent=1, default=float))
        return 0
    from ..dataset import read_setup

    print(markdown(report, load_robot(read_setup(args.dataset).robot).joint_names))
    if args.out:
        print(f"wrote {Path(args.out) / 'report.json'}, report.md, gap.png, patterns.png, effect.png, {html}")
    return 0


def register(sub) -> None:
    p = sub.add_parser(
        "diagnose", help="detect, name and add the effects the paper's model misses (needs repeat scans)"
    )
    p.add_argument("dataset", type=Path)
    p.add_argument(
        "--out",
        type=output_dir,
        help="write report.json, report.md, the figures, model.json and report.html here",
    )
    p.add_argument(
        "--alpha", type=float, default=0.01, help="family-wise false-alarm rate (default %(default)s)"
    )
    p.add_argument(
        "--candidates",
        help="comma-separated candidate names (default: all but the opt-in geometric_error; with "
        "--statics paper, the clean world's gravity_stiffness, load_dependent_jacobian and exact_kinematics too; "
        "none: the detection alone)",
    )
    p.add_argument("--statics", choices=("exact", "paper"),
                   help="baseline: the paper's model with the clean world's exact statics (default), or as printed")  # fmt: skip
    p.add_argument("--rank", choices=("press", "bic"), help="how to rank the significant candidates: press (their leave-one-test-out "
                   "prediction error, the default) or bic")  # fmt: skip
    p.add_argument("--scale-tolerance", type=number(*SCALE_TOLERANCE_RANGE_PPM, "ppm"), default=SCALE_TOLERANCE_PPM,
                   metavar="PPM", help="the scale check on the block's declared size: |scale| up to this is the block's "
                   "and its edges' tolerance (default %(default)g ppm: sharp edges known to 0.08 mm on 80 mm)")  # fmt: skip
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=_cmd_diagnose)
