"""``vtestbed sweep SCENARIO --out DIR``: run a Monte Carlo campaign (see :mod:`vtestbed.sweep`)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from ..files import dumps
from .args import integer, output_dir


def _text_report(report: dict) -> str:
    lines = [f"{report['trials']} trials ({report['failed']} failed)"]
    for axis, t in report["trends"].items():
        word = "grows" if axis != "n_tests" else "shrinks"
        lines.append(f"RMS error {word} along {axis}: {t['monotonic']} of {t['slices']} (cell, joint) slices")
    s = report["spread_check"]
    lines.append(
        f"spread / predicted std: median {s['ratio_median']:.2f}, range {s['ratio_min']:.2f}..{s['ratio_max']:.2f}; "
        f"{s['inside']} of {s['cells']} (cell, joint) within x{s['factor']:g}"
    )
    for n, b in s.get("by_n_tests", {}).items():
        lines.append(
            f"  {n} tests: {b['inside']} of {b['cells']} within, median ratio {b['ratio_median']:.2f}"
        )
    if report["pose_choice"]:
        lines.append(
            "pose choice (error score = geometric mean over joints of the RMS error; ratio to kappa_regions):"
        )
        for r in report["pose_choice"]:
            lines.append(
                f"  n={r['n_tests']:3d} {r['pose_set']:15s} score {r['score_pct']:7.3f} %  ratio "
                f"{r['ratio_to_kappa']:.2f} [{r['ratio_lo95']:.2f}, {r['ratio_hi95']:.2f}]  {r['verdict']}"
            )
    lines += [f"{k}: {v}" for k, v in report["files"].items()]
    return "\n".join(lines)


def _cmd_sweep(args) -> int:
    # imported here, not at the top: building the parser for another command must not load them
    from ..campaigns.report import write_report
    from ..campaigns.runner import sweep
    from ..campaigns.spec import load_campaign
    from ..campaigns.store import MANIFEST

    campaign = load_campaign(args.scenario)  # every error is raised here, before any work
    if args.dry_run:
        print(dumps(campaign.to_dict() | {"trials_total": campaign.n_trials}, indent=1))
        return 0
    df = sweep(campaign, args.out, workers=args.workers, scheduler=args.scheduler,
               progress=not args.quiet, batch_trials=args.batch_trials,
               allow_code_change=args.allow_code_change)  # fmt: skip
    if not args.no_report:
        manifest = json.loads((Path(args.out) / MANIFEST).read_text())
        report = write_report(df, Path(args.out) / "report", manifest)
        print(_text_report(report))
        from ..reports import write_report as write_html

        print(f"wrote {write_html(args.out)}")
    else:
        print(f"{len(df)} trials in {args.out}", file=sys.stderr)
    return 0


def register(sub) -> None:
    p = sub.add_parser("sweep", help="run a Monte Carlo campaign ([campaign] table) into Parquet; resumable")
    p.add_argument("scenario", type=Path, help="scenario TOML file with a [campaign] table")
    p.add_argument("--out", type=output_dir, required=True, help="results folder (rerun to complete it)")
    p.add_argument(
        "--workers", type=integer(1, 1024), default=1, help="local worker processes (default %(default)s)"
    )
    p.add_argument(
        "--scheduler", help="Dask scheduler address, e.g. tcp://127.0.0.1:8786 (overrides --workers)"
    )
    p.add_argument("--batch-trials", type=integer(1), help="trials per task (default: about 2 s of work)")
    p.add_argument("--allow-code-change", action="store_true",
                   help="complete a folder started by other vtestbed code (results are mixed)")  # fmt: skip
    p.add_argument("--dry-run", action="store_true", help="validate and list the campaign, run nothing")
    p.add_argument("--no-report", action="store_true", help="skip the summary table and figures")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_sweep)
