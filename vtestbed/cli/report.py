"""``vtestbed report DIR [--out FILE]``: one self-contained HTML page of a run, campaign, diagnosis
or discovery."""

from __future__ import annotations

from pathlib import Path

from .args import output_file


def _cmd_report(args) -> int:
    from ..reports import write_report

    # a folder holding no result raises a ReportError naming the files looked for (exit 2)
    out = write_report(args.dir, args.out)
    print(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB)")
    return 0


def register(sub) -> None:
    p = sub.add_parser(
        "report",
        help="write DIR/report.html: a self-contained page of a run, campaign, diagnosis or discovery folder",
    )
    p.add_argument(
        "dir",
        type=Path,
        help="a folder written by 'vtestbed run', 'sweep', 'diagnose --out' or 'discover --out'",
    )
    p.add_argument(
        "--out",
        type=output_file,
        help="the HTML file to write (default DIR/report.html; its folder is created)",
    )
    p.set_defaults(func=_cmd_report)
