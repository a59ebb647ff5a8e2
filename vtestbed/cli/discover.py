"""``vtestbed discover SCENARIO --out DIR``: diagnose, propose discrimination tests, run them, diagnose again."""

from __future__ import annotations

from pathlib import Path

from ..files import dumps
from ..researcher.block_size import SCALE_TOLERANCE_PPM, SCALE_TOLERANCE_RANGE_PPM
from .args import integer, number, output_dir


def _cmd_discover(args) -> int:
    from ..discovery import discover, markdown
    from ..errors import OutOfRangeError, require_level
    from ..scenario import load_scenario

    require_level(args.alpha, "--alpha")
    if args.max_extra_tests is not None and args.max_extra_tests < args.extra_tests:
        raise OutOfRangeError(
            f"--max-extra-tests = {args.max_extra_tests} must be at least --extra-tests = {args.extra_tests}"
        )
    result = discover(
        load_scenario(args.scenario), args.out, extra_tests=args.extra_tests, alpha=args.alpha,
        criterion=args.criterion, n_poses=args.n_poses, progress=not args.quiet, always=args.always,
        rounds=args.rounds, separation=args.separation, max_extra_tests=args.max_extra_tests,
        scale_tolerance_ppm=args.scale_tolerance,
    )  # fmt: skip
    html = _pages(Path(args.out), len(result["rounds"]))
    if args.json:
        print(dumps(result, indent=1, default=float))
        return 0
    print(markdown(result))
    print(
        f"wrote {Path(args.out) / 'discover.json'}, discover.md, {html} (each round's diagnosis: its report.html)"
    )
    return 0


def _pages(out: Path, rounds: int) -> Path:
    """The HTML pages: each stage's diagnosis (``round<k>/diagnose/report.html``), then the
    discovery page that points to them (``report.html``)."""
    from ..reports import write_report

    for k in range(rounds + 1):
        write_report(out / f"round{k}" / "diagnose")
    return write_report(out)


def register(sub) -> None:
    # literals, not imports: building the parser must not load MuJoCo (tests check they match)
    p = sub.add_parser(
        "discover",
        help="simulate, diagnose, propose tests that separate confusable effects, run them, diagnose again",
    )
    p.add_argument("scenario", type=Path)
    p.add_argument(
        "--out",
        type=output_dir,
        required=True,
        help="output folder (round0/, round1/, discover.json, discover.md, report.html)",
    )
    p.add_argument("--extra-tests", type=integer(1, 50), default=10,
                   help="number of discrimination tests, 1-50 (default %(default)s)")  # fmt: skip
    p.add_argument(
        "--alpha", type=float, default=0.01, help="family-wise false-alarm rate (default %(default)s)"
    )
    p.add_argument("--criterion", default="T", choices=("T", "difference"),
                   help="T-optimal (models refitted, default) or the whitened difference of the fitted models")  # fmt: skip
    p.add_argument("--n-poses", type=integer(1, 10000), default=150,
                   help="random poses of the candidate pool, each with every feasible hook, ring and tension "
                        "(default %(default)s)")  # fmt: skip
    p.add_argument("--always", action="store_true",
                   help="run the extra tests even after a decisive diagnosis: confirm the first name against "
                        "its closest rivals, or screen for an effect just below the level")  # fmt: skip
    p.add_argument("--rounds", type=integer(1, 5), default=1,
                   help="rounds of extra tests at most, 1-5: after the first, another runs while the "
                        "diagnosis is still undecided (default %(default)s)")  # fmt: skip
    p.add_argument("--separation", type=number(0.0, 1e9, low_open=True), nargs="?", const=25.0, default=None, metavar="T",
                   help="size each round: from --extra-tests, one more test at a time until the smallest "
                        "predicted T over the rival pairs reaches T (noise-floor units; 25 without a value: "
                        "a 1-df test at 0.1 %% with 95 %% power), and as many as the block's scale check "
                        "needs to decide with 98 %% power at its estimate")  # fmt: skip
    p.add_argument("--max-extra-tests", type=integer(1, 50), default=None,
                   help="a sized round's largest size, --extra-tests to 50 (default 3 x --extra-tests)")  # fmt: skip
    p.add_argument("--scale-tolerance", type=number(*SCALE_TOLERANCE_RANGE_PPM, "ppm"), default=SCALE_TOLERANCE_PPM,
                   metavar="PPM", help="every diagnosis's tolerance for the scanner's scale measured on the block, as "
                   "vtestbed diagnose --scale-tolerance (default %(default)g ppm)")  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=_cmd_discover)
