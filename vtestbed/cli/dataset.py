"""``vtestbed dataset import``: a lab's raw files (F/T streams in CSV, PLY/PCD/XYZ clouds) as a dataset.

Units: the clouds in m or mm (``--cloud-units``), the streams' torques in N*m or N*mm
(``--torque-units``), windows in seconds; the dataset written is SI (docs/lab_data.md).
"""

from __future__ import annotations

import argparse
import math

from .args import number, output_dir


def window_option(text: str) -> tuple[float, float]:
    """``START:END`` in seconds, finite, ``START < END`` (an argparse ``type=``)."""
    parts = text.split(":")
    try:
        start, end = (float(p) for p in parts) if len(parts) == 2 else (math.nan, math.nan)
    except ValueError:
        start = end = math.nan
    if not (math.isfinite(start) and math.isfinite(end) and start < end):
        raise argparse.ArgumentTypeError(
            f"must be START:END in seconds with START < END (e.g. 2.0:3.5), got {text!r}"
        )
    return start, end


def _cmd_import(args) -> int:
    from ..lab_import import WINDOWS_FILE, ImportOptions, import_dataset

    options = ImportOptions(
        args.cloud_units, args.torque_units, args.window, args.window_length, args.settle_z
    )
    result = import_dataset(args.manifest, args.out, options)
    n_id = sum(r.group == "identification" for r in result.records)
    print(f"{len(result.records)} tests ({n_id} identification) imported into {result.root}")
    print(f"{'test':8}{'state':10}{'window [s]':>18}{'n':>7}{'Fz mean [N]':>14}{'Fz sem [N]':>12}{'tau':>6}")
    for (tid, state), r in result.readings.items():
        window = f"{r.start:.3f}-{r.end:.3f}" + ("*" if r.automatic else " ")
        print(f"{tid:8}{state:10}{window:>18}{r.n:7d}{r.mean[2]:14.4f}{r.sem[2]:12.2e}{r.tau[2]:6.1f}")
    print(f"(* the quietest window found; every axis's mean, std, sem and tau: {result.root / WINDOWS_FILE})")
    return 0


def register(sub) -> None:
    p = sub.add_parser("dataset", help="dataset tools: import a lab's raw files")
    dsub = p.add_subparsers(dest="dataset_command", required=True)
    imp = dsub.add_parser(
        "import",
        help="build a dataset from a manifest of F/T stream CSVs and PLY/PCD/XYZ clouds",
        description="Build a dataset folder (setup.json, tests.csv, clouds/) from a lab's raw files "
        "listed in a TOML manifest (docs/lab_data.md).",
    )
    imp.add_argument("manifest", help="the TOML manifest (paths in it are relative to its folder)")
    imp.add_argument(
        "--out", type=output_dir, required=True, help="the dataset folder to write (new or empty)"
    )
    imp.add_argument(
        "--cloud-units", choices=("m", "mm"), help="unit of the cloud files (overrides [units] cloud)"
    )
    imp.add_argument(
        "--torque-units", choices=("Nm", "Nmm"), help="unit of the streams' torque columns (default Nm)"
    )
    window = imp.add_mutually_exclusive_group()  # a given window, or the length of the quietest one
    window.add_argument(
        "--window", type=window_option, metavar="START:END",
        help="static window of every stream in s (a test's window_<state>_s wins); default: the quietest window",
    )  # fmt: skip
    window.add_argument(
        "--window-length", type=number(0, 1e4, "s", low_open=True), metavar="S",
        help="length of the automatic (quietest) window in s (default 1.0, or the manifest's)",
    )  # fmt: skip
    imp.add_argument(
        "--settle-z", type=number(0, 1e12, low_open=True), default=5.0, metavar="Z",
        help="a window whose halves' means differ by more than Z standard errors has not settled "
        "(default %(default)s; a large Z switches the check off)",
    )  # fmt: skip
    imp.set_defaults(func=_cmd_import)
