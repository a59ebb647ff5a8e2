"""``vtestbed simulate | identify | run | demo``: the virtual experiment end to end."""

from __future__ import annotations

from pathlib import Path

from ..files import dumps
from .args import output_dir, print_notes

IDENTIFY_METHODS = ("ols", "fgls", "fgls_pooled", "gls_floor")
REFERENCES = ("scan", "mean")  # researcher.scan_mean.REFERENCES (a test keeps them equal)

SCENARIOS_DIR = Path(__file__).resolve().parents[2] / "scenarios"


def _print_run(summary: dict, out: Path) -> None:
    print(
        f"\n{summary['scenario']}: {summary['n_tests']} tests, method {summary['method']}, seed {summary['seed']}"
        + (", displacements against the mean unloaded scan" if summary.get("reference") == "mean" else "")
    )
    print(summary["table"])
    print_notes(summary["identification"]["warnings"])
    if summary["validation"]:
        errs = [max(v["rel_err_translation"], v["rel_err_rotation"]) for v in summary["validation"]]
        print(f"validation poses: worst relative displacement error {max(errs) * 100:.2f} %")
    t = summary["timings_s"]
    print("time [s]: " + ", ".join(f"{k} {v:.2f}" for k, v in t.items()))
    print(f"wrote {out / 'result.json'}" + "".join(f", {p}" for p in summary["figures"].values()))


def _cmd_simulate(args) -> int:
    from ..experiment import simulate
    from ..scenario import load_scenario

    out = simulate(load_scenario(args.scenario), args.out, progress=not args.quiet)
    print(f"dataset written to {out}")
    return 0


def _identify_with_model(args) -> int:
    """``identify --model FILE``: the paper's model plus the file's terms, against the noise floor."""
    from ..researcher.model_file import identify_with_model

    out = identify_with_model(args.dataset, args.model)
    if args.json:
        print(dumps(out, indent=1, default=float))
        return 0
    model = out["model"]
    print(f"model: the paper's plus {', '.join(model['terms']) or 'nothing'}; chi^2 {model['chi2']:.1f} "
          f"with {model['dof']} degrees of freedom against the noise floor (p = {model['p_value']:.3g})")  # fmt: skip
    for name, k, s in zip(
        out["joint_names"], model["stiffness_Nm_per_rad"], model["stiffness_std_Nm_per_rad"]
    ):
        print(f"{name:8}{k * 1e3:18.4e} +- {s * 1e3:.2e} N*mm/rad")
    for label, params in model["parameters"].items():
        stds = model["parameters_std"][label]
        print(f"{label}: " + ", ".join(f"{p} = {v:.4g} +- {stds[p]:.2g}" for p, v in params.items()))
    if out["validation"]:
        val = out["validation"]
        print(f"validation prediction error / noise floor: {val['ratio_to_floor']:.2f} "
              f"(a correct model reaches {val['expected_ratio']:.2f} on average)")  # fmt: skip
    return 0


def _cmd_identify(args) -> int:
    if args.model is not None:
        if args.reference == "scan":
            from ..errors import VtestbedError

            raise VtestbedError(
                "identify --model measures every displacement against the mean of its test's unloaded "
                "scans, as diagnose does: --reference scan cannot be combined with --model"
            )
        return _identify_with_model(args)
    from ..comparison import compare, read_truth
    from ..dataset_identification import identify_dataset_with_floor

    reference = args.reference or "scan"
    setup, measurements, result, floor = identify_dataset_with_floor(  # floor: None without repeats
        args.dataset, args.method, progress=not args.quiet, strict=args.strict, reference=reference
    )
    out = {"dataset": str(args.dataset), "reference": reference, **result.as_dict()}
    if floor is not None:
        out["noise_floor"] = floor.as_dict()
    truth = None if args.no_truth else read_truth(args.dataset, dof=len(result.joint_names))  # names the file
    if truth is not None:
        out["joints"] = compare(result, truth)
    if args.json:
        print(dumps(out, indent=1))
        return 0
    print(
        f"{'joint':8}{'k_est [N*mm/rad]':>18}{'k_std':>12}{'k_std/k [%]':>12}"
        + (f"{'rel_err [%]':>12}" if truth else "")
    )
    for i, name in enumerate(result.joint_names):
        line = (
            f"{name:8}{result.stiffness[i] * 1e3:18.4e}{result.stiffness_std[i] * 1e3:12.2e}"
            f"{result.stiffness_std[i] / result.stiffness[i] * 100:12.3f}"
        )
        if truth:
            line += f"{out['joints'][i]['rel_err'] * 100:12.3f}"
        print(line)
    print(f"condition number {result.condition_number:.3g}, reduced chi^2 {result.chi2_reduced:.3g}")
    if floor is not None:
        print(floor.summary())
    print_notes(result.warnings)
    return 0


def _cmd_run(args) -> int:
    from ..experiment import run
    from ..scenario import load_scenario

    out = Path(args.out)
    summary = run(
        load_scenario(args.scenario),
        out,
        progress=not args.quiet,
        figures=not args.no_figures,
        replace_stale=getattr(args, "replace_stale", False),
        strict=getattr(args, "strict", False),
    )
    _print_run(summary, out)
    if not args.no_figures:
        from ..reports import write_report

        print(f"wrote {write_report(out)}")
    return 0


def _cmd_demo(args) -> int:
    args.scenario = SCENARIOS_DIR / "kr60_paper.toml"
    args.no_figures = False
    args.replace_stale = True  # the demo's own folder: a dataset of an older scenario is replaced
    return _cmd_run(args)


def register(sub) -> None:
    p = sub.add_parser("simulate", help="run a scenario in the virtual lab and write a measurement dataset")
    p.add_argument("scenario", type=Path)
    p.add_argument("--out", type=output_dir, required=True)
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=_cmd_simulate)

    p = sub.add_parser("identify", help="identify joint stiffness from a dataset (simulated or from a lab)")
    p.add_argument("dataset", type=Path)
    # scenario.METHODS, written out so that the command does not import the scenario module (a test keeps them equal)
    p.add_argument("--method", default="fgls", choices=IDENTIFY_METHODS)
    p.add_argument("--json", action="store_true")
    p.add_argument("--no-truth", action="store_true", help="do not compare with truth.json even if present")
    p.add_argument(
        "--reference",
        choices=REFERENCES,
        help="what each displacement is measured against: 'scan', the test's own unloaded scan (the "
        "paper's; the default), or 'mean', the mean of the test's unloaded scans (its own and its repeats: "
        "1.6x the information per test with 3 repeats; needs repeat scans of every test; with loaded_repeats.csv "
        "the loaded end is averaged too, unless the creep check says the loaded block moved between its scans)",
    )
    p.add_argument(
        "--model",
        type=Path,
        help="model.json from 'vtestbed diagnose': add its terms (needs repeat scans; measured against "
        "the mean unloaded scan, as diagnose does)",
    )
    p.add_argument(
        "--strict",
        action="store_true",
        help="refuse implausible tests (a block that did not move, moved against or far beyond its load, a force that misses the block) instead of warning",
    )
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=_cmd_identify)

    p = sub.add_parser(
        "run", help="simulate + identify + compare with the truth; writes result.json and figures"
    )
    p.add_argument("scenario", type=Path)
    p.add_argument("--out", type=output_dir, required=True)
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures and report.html")
    p.add_argument(
        "--strict",
        action="store_true",
        help="refuse implausible tests (a block that did not move, moved against or far beyond its load, a force that misses the block) instead of warning",
    )
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=_cmd_run)

    p = sub.add_parser("demo", help="run the paper's scenario (scenarios/kr60_paper.toml)")
    p.add_argument("--out", type=output_dir, default="runs/demo")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=_cmd_demo)
