"""``diagnose``: the discrepancy workflow on one dataset, start to end, and its report.

Reads a dataset (with repeat scans for the noise floor, and validation tests if it has them),
never the truth. Detects (chi^2 of the paper's model against the noise floor), names the missing
effects (:func:`.diagnose.name_effects`; the scanner's scale measured on the block or ruled out
where its size decides, :mod:`.scale_term`), adds them, and compares the validation prediction
error before and after. Writes ``report.json``, ``report.md``, ``gap.png``, ``patterns.png``, ``effect.png`` and ``model.json`` (the named
terms, for ``vtestbed identify --model``) when given a folder.
Units: SI; stiffness in N*m/rad.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..files import write_json_atomic, write_text_atomic
from ..transforms import DISPLACEMENT_COMPONENTS as COMPONENTS
from . import block_size
from .block_size import ScaleCheck
from .candidates import ModelContext, candidates
from .diagnose import (
    CONFUSABLE_MARGIN,
    DEFAULT_ALPHA,
    DEFAULT_RANK,
    Whitener,
    absorbed_by,
    confusable_margin,
    rank_label,
    require_rank,
    require_tests,
    round_stand_ins,
    validation_gap,
)
from .discrepancy_plots import plot_effect, plot_gap, plot_patterns
from .kinematics import ArmKinematics
from .loaded_scatter import LoadedScatter
from .model_file import (
    DEFAULT_STATICS,
    baseline_statics,
    default_candidates,
    model_file,
    require_names,
    require_outside,
)
from .naming_run import run_naming
from .scale_term import named_labels, named_note, report_scale, with_measured
from .scan_mean import load_with_floor


def diagnose(
    root,
    alpha: float = DEFAULT_ALPHA,
    names=None,
    out=None,
    statics: str = DEFAULT_STATICS,
    rank_by: str = DEFAULT_RANK,
    scale_tolerance_ppm: float = block_size.SCALE_TOLERANCE_PPM,
) -> dict:
    """Run the workflow on the dataset in ``root``; returns the report (and writes it to ``out``).

    ``statics="exact"`` (default) takes the paper's model with the clean world's exact statics
    (gravity at the sagged pose, load-dependent Jacobian, exact kinematics: :mod:`.statics`) as
    the baseline, so that candidates compete only for what every lab does not share;
    ``"paper"`` takes the paper's linear model as it is, and the three clean-world gaps
    (``gravity_stiffness``, ``load_dependent_jacobian``, ``exact_kinematics``) join the
    candidates. ``names``: the candidate names, a sequence or one comma-separated string (default
    :func:`default_candidates`; ``()`` tests none, the detection alone: the report's model is then
    the baseline). ``rank_by``:
    how the significant candidates are ranked (:data:`.diagnose.RANK_CRITERIA`; default the
    leave-one-test-out prediction error). ``scale_tolerance_ppm``: the tolerance of the scale
    check on the block's declared size (:mod:`.block_size`); where it decides, ``scanner_scale``
    is measured on the block or ruled out instead of tested (:mod:`.scale_term`).
    """
    require_rank(rank_by)  # before any work: the dataset's own errors come after
    block_size.require_tolerance(scale_tolerance_ppm)
    if isinstance(names, str):  # "a,b" as on the command line, not its characters
        names = tuple(n.strip() for n in names.split(","))
    names = default_candidates(statics) if names is None else tuple(names)
    if names:  # none (``names=()``, ``--candidates none``): the detection alone
        require_names(names, "--candidates")
    require_outside(statics, names, "--candidates")
    # displacements against the mean unloaded scan; loaded repeats left out if the creep check fails at alpha
    setup, measurements, floor = load_with_floor(root, alpha, edges=True)
    kin = ArmKinematics.for_setup(setup)
    ident = [m for m in measurements if m.group == "identification"]
    pool = candidates(kin, names)
    if pool:  # the candidate with the most parameters must still leave a residual to test
        widest = max(pool, key=lambda c: len(c.params))
        require_tests(root, len(ident), kin.robot.dof, len(widest.params), f"candidate {widest.label!r}",
                      "Record more tests or leave it out (--candidates)")  # fmt: skip
    # detect, settle the scale on the block (measured, ruled out or tested), name: naming_run
    run = run_naming(measurements, setup, kin, baseline_statics(statics, kin, setup), floor, pool, alpha,
                     rank_by, scale_tolerance_ppm)  # fmt: skip
    ctx, ctx_val, white, base = run.ctx, run.ctx_val, run.white, run.base
    scale, term, pool, fixed, fixed_val = run.scale, run.term, run.pool, run.fixed, run.fixed_val
    chosen, steps, final = run.chosen, run.steps, run.final
    names_chosen = {c.label for c in chosen}
    named = named_labels([c.label for c in chosen], term)  # a measured scale first
    absorbed = {f"{c.label} {param}": note for c in chosen for param, note in c.absorbed}
    for cand in pool:
        if cand.label not in names_chosen:
            note = absorbed_by(fixed, white, cand, final.compliance, kin.robot.joint_names)
            if note:
                absorbed[cand.label] = note
    std = floor.component_std
    report = {
        "dataset": str(root),
        "alpha": alpha,
        "rank_by": rank_by,
        "statics": statics,
        "candidates": list(names),
        "noise_floor": {"component_std": std.tolist(), "n_samples": int(floor.n_samples),
                        "reference_scans": floor.reference_scans, "loaded_scans": floor.loaded_scans,
                        "loaded_scatter": floor.loaded_scatter and floor.loaded_scatter.to_dict(),
                        # the F/T readings' noise in the prediction (reading_noise), tested with the scans'
                        "reading_std": None if floor.reading_std is None else floor.reading_std.tolist()},
        "scale_check": scale and scale.to_dict(),  # None: a mesh target, or fewer than 3 tests
        "scale_term": term and term.to_dict(),  # None: scanner_scale not among the candidates
        "detect": {
            "chi2": base.chi2, "dof": base.dof, "p_value": base.p_value,
            "normalised_residual_rms": (np.sqrt(np.mean(base.residuals**2, axis=0)) / std).tolist(),
            "per_test": (per_test := _per_test(white, base.residuals)),
            "features": (features := pose_features(ctx)),
            "patterns": residual_patterns(per_test, features),
            "model_rejected": bool(base.p_value < alpha),
        },
        "named": named,
        "absorbed": absorbed,
        "dropped": dropped_notes(steps, names_chosen),
        "confusable": [
            {"chosen": s.chosen, "runner_up": s.runner_up, "delta": s.delta, "delta_bic": s.delta_bic}
            for s in steps if s.chosen in names_chosen and s.delta is not None and s.delta < CONFUSABLE_MARGIN
        ],
        "rounds": round_records(steps),
        "baseline": base.to_dict(),
        "model": with_measured(final.to_dict(), term),
        "validation": {"before": validation_gap(ctx_val, white, base, []),
                       "after": validation_gap(fixed_val, white, final, chosen)},
        "effect": _effect(white, base, final, named),
        "identification_fit": {"before": float(np.sqrt(base.chi2 / (6 * ctx.n_tests))),
                               "after": float(np.sqrt(final.chi2 / (6 * ctx.n_tests))),
                               "per_test_after": _per_test(white, final.residuals),
                               "test_ids": [m.test_id for m in ident]},
    }  # fmt: skip
    if out is not None:
        write_report(report, Path(out), kin.robot.joint_names)
        write_json_atomic(Path(out) / "model.json", model_file(report, setup.robot, statics))
    return report


def round_records(steps) -> list[dict]:
    """The report's ``rounds``: one record per :class:`~.diagnose.Step` of the stepwise search (what
    :mod:`vtestbed.design.rivals` reads to find the rivals a diagnosis leaves undecided)."""
    return [{"base": list(s.base_terms), "base_chi2": s.base_chi2, "level": s.level, "chosen": s.chosen,
             "runner_up": s.runner_up, "delta": s.delta, "delta_bic": s.delta_bic, "tests": s.tests,
             "dropped": list(s.dropped), "overlap_of": s.overlap_of}
            for s in steps]  # fmt: skip


def dropped_notes(steps, kept=()) -> dict:
    """Per term named in one round and dropped in a later one (and not ``kept`` in the end): why.

    Such a term stood in for the terms named after it: given them, it explains nothing beyond the
    noise (:func:`.diagnose.name_effects`' backward step)."""
    out = {}
    for k, step in enumerate(steps, start=1):
        for d in (d for d in step.dropped if d["label"] not in kept):
            first = next(i for i, s in enumerate(steps, start=1) if s.chosen == d["label"])
            out[d["label"]] = (
                f"named in round {first}, dropped in round {k}: it stood in for {', '.join(d['others'])} "
                f"(given them its likelihood ratio is {d['lr']:.1f} on {d['df']} parameters, "
                f"p = {d['p_value']:.2g} >= {d['level']:.2g})"
            )
    return out


def stand_ins(report: dict) -> dict:
    """Per named term: the candidates that reproduce at least ``STAND_IN_R2`` of its fitted pattern
    in the round that named it, as (label, share) pairs, largest first (none: left out)."""
    out = {}
    for rnd in (r for r in report["rounds"] if r["chosen"] in report["named"]):
        if alike := round_stand_ins(rnd, rnd["chosen"]):
            out[rnd["chosen"]] = alike
    return out


def pose_features(ctx: ModelContext) -> dict:
    """Per test: joint angles [deg], the load's joint torques J^T dW [N*m], the force's elevation and
    azimuth in the base frame [deg]: what a residual pattern can be read against."""
    feats = {f"q{j + 1}_deg": [] for j in range(ctx.kin.robot.dof)}
    feats |= {f"tau{j + 1}_Nm": [] for j in range(ctx.kin.robot.dof)}
    feats |= {"force_elevation_deg": [], "force_azimuth_deg": []}
    for t, m in enumerate(ctx.measurements):
        tau = m.jacobian.T @ m.wrench
        force = ctx.block[t][:3, :3] @ m.wrench[:3]  # base axes
        for j in range(len(m.q)):
            feats[f"q{j + 1}_deg"].append(float(np.degrees(m.q[j])))
            feats[f"tau{j + 1}_Nm"].append(float(tau[j]))
        feats["force_elevation_deg"].append(float(np.degrees(np.arcsin(force[2] / np.linalg.norm(force)))))
        feats["force_azimuth_deg"].append(float(np.degrees(np.arctan2(force[1], force[0]))))
    return feats


def detection_alone(report: dict) -> bool:
    """Whether ``report`` tested no candidate (``--candidates none``; a report written before
    reports recorded their candidates did test them)."""
    return report.get("candidates") == []


def no_candidates_text(option: str = "--candidates none") -> str:
    """What the reports say instead of the names when :func:`detection_alone`."""
    return f"No candidate was tested: the detection alone ({option})."


EXACT_PATTERN_TESTS = 8  # up to 8! = 40320 orderings the p-value is exact (see spearman)


def residual_patterns(per_test: list, features: dict) -> dict:
    """Spearman correlation (and its p-value) of the per-test residual with each pose feature."""
    out = {}
    for name, values in features.items():
        if len(set(np.round(values, 9))) < 3:  # a feature that does not vary (A1 = 0 everywhere)
            out[name] = {"rho": None, "p_value": None, "note": "constant over the tests"}
            continue
        rho, p = spearman(values, per_test)
        out[name] = {"rho": rho, "p_value": p}
    return out


def spearman(x, y) -> tuple[float, float]:
    """Spearman's rho of ``x`` and ``y`` (n,) and its two-sided p-value.

    Up to :data:`EXACT_PATTERN_TESTS` tests the p-value counts every ordering of ``y``'s ranks
    (exact; scipy's t approximation says p = 0 for a perfect rank order of 3 tests, whose exact
    p-value is 1/3); above, scipy's.
    """
    from itertools import permutations

    from scipy.stats import rankdata, spearmanr

    rho, p = spearmanr(x, y)
    n = len(x)
    if n <= EXACT_PATTERN_TESTS and np.isfinite(rho):
        rx, ry = rankdata(x), rankdata(y)
        rx, ry = rx - rx.mean(), ry - ry.mean()
        shuffled = ry[np.array(list(permutations(range(n))))]  # (n!, n)
        r = shuffled @ rx / np.sqrt((rx @ rx) * (ry @ ry))
        p = np.mean(np.abs(r) >= abs(rho) - 1e-12)
    return float(rho), float(p)


def _effect(white: Whitener, base, final, labels: list[str]) -> dict:
    """What the named terms explain, per test and whitened component: the baseline's residual and
    the part the named model removes from it (``base - final`` residuals). The fraction of the
    baseline's chi^2 removed is ``1 - chi2_final / chi2_base``; with nothing named, 0."""
    before = white(base.residuals.reshape(-1)).reshape(-1, 6)
    after = white(final.residuals.reshape(-1)).reshape(-1, 6)
    return {"terms": labels, "explained_fraction": float(1.0 - np.sum(after**2) / np.sum(before**2)),
            "baseline_whitened": before.tolist(), "explained_whitened": (before - after).tolist()}  # fmt: skip


def _per_test(white: Whitener, residuals: np.ndarray) -> list:
    """RMS whitened residual of each test (1 = as large as the noise floor)."""
    return np.sqrt(np.sum(white(residuals.reshape(-1)).reshape(-1, 6) ** 2, axis=1) / 6).tolist()


def _reference_text(scans: int, loaded: int = 1) -> str:
    """How the displacements were measured (:mod:`.scan_mean`)."""
    if scans == 1 and loaded == 1:
        return "displacements from one unloaded scan, as the paper measures them"
    if loaded == 1:
        return f"displacements against the mean of {scans} unloaded scans per test"
    return f"displacements from the mean of {scans} unloaded to the mean of {loaded} loaded scans per test"


def markdown(report: dict, joint_names) -> str:
    det, val = report["detect"], report["validation"]
    lines = [
        f"# Discrepancy report: {report['dataset']}",
        "",
        f"Noise floor (repeat scans, {report['noise_floor']['n_samples']} samples; "
        f"{_reference_text(report['noise_floor'].get('reference_scans', 1), report['noise_floor'].get('loaded_scans', 1))}): "
        + ", ".join(f"{c} {s * 1e6:.2f}" for c, s in zip(COMPONENTS, report["noise_floor"]["component_std"]))
        + " (um, urad)"
        + _reading_text(report["noise_floor"].get("reading_std"))
        + _scatter_text(report["noise_floor"].get("loaded_scatter"), report["alpha"]),
        "",
        f"**Detect.** The paper's model ({report['statics']} statics) against the noise floor: chi^2 = {det['chi2']:.1f} with {det['dof']} "
        f"degrees of freedom, p = {det['p_value']:.3g}: "
        + ("the model is rejected." if det["model_rejected"] else "consistent with the noise."),
        "Strongest residual patterns (Spearman rho of the per-test residual with a pose feature): "
        + ", ".join(
            f"{n} {v['rho']:+.2f} (p {v['p_value']:.2g})"
            for n, v in sorted(
                ((n, v) for n, v in det["patterns"].items() if v["rho"] is not None),
                key=lambda kv: kv[1]["p_value"],
            )[:3]
        )
        + ".",
        "",
        f"**Name.** {no_candidates_text('`--candidates none`')}"
        if detection_alone(report)
        else "**Name.** "
        + (
            ", ".join(f"`{n}`{named_note(report, n)}" for n in report["named"])
            if report["named"]
            else "nothing"
        )
        + f" (likelihood ratio, Bonferroni at alpha = {report['alpha']:g}, ranked by {rank_label(report)}).",
    ]
    for label, note in {**report["absorbed"], **report.get("dropped", {})}.items():
        lines.append(f"- `{label}`: {note}")
    for c in report["confusable"]:
        lines.append(f"- `{c['chosen']}` could also be `{c['runner_up']}` ({confusable_margin(report, c)}): "
                     "more varied tests would separate them")  # fmt: skip
    for chosen, alike in stand_ins(report).items():
        lines.append(f"- `{chosen}`'s pattern is also reproduced by "
                     + ", ".join(f"`{label}` ({share:.0%})" for label, share in alike)
                     + ": it may stand for one of them (`vtestbed discover --always` tests them against each other)")  # fmt: skip
    if report.get("scale_check"):  # reports before 2026-11-29 have none
        lines += ["", "**Scale.** " + ScaleCheck.from_dict(report["scale_check"]).sentence()]
    elif "scale_check" in report:
        lines += ["", f"**Scale.** {block_size.NOT_CHECKED}"]
    # what the naming made of the scale (none: no scanner_scale candidate, or an older report)
    if scale := report_scale(report):
        lines[-1] += " " + scale.sentence()
    lines += ["", "| joint | k before [N*mm/rad] | k after [N*mm/rad] |", "| --- | --- | --- |"]
    before, after = report["baseline"], report["model"]
    rows = zip(
        joint_names,
        before["stiffness_Nm_per_rad"],
        after["stiffness_Nm_per_rad"],
        after["stiffness_std_Nm_per_rad"],
    )
    for name, k0, k1, s1 in rows:
        lines.append(f"| {name} | {k0 * 1e3:.4e} | {k1 * 1e3:.4e} +- {s1 * 1e3:.2e} |")
    for label, params in report["model"]["parameters"].items():
        stds = report["model"]["parameters_std"][label]
        lines.append(
            f"- `{label}`: " + ", ".join(f"{p} = {v:.4g} +- {stds[p]:.2g}" for p, v in params.items())
        )
    fit = report["identification_fit"]
    lines += [
        "",
        f"**Show.** Identification residual / noise floor: {fit['before']:.2f} before, {fit['after']:.2f} after.",
    ]
    if val["before"]:
        lines.append(f"Validation prediction error / noise floor: {val['before']['ratio_to_floor']:.2f} before, "
                     f"{val['after']['ratio_to_floor']:.2f} after.{_reachable(val)}")  # fmt: skip
    return "\n".join(lines) + "\n"


def _reading_text(reading_std: list | None) -> str:
    """The F/T readings' noise the model is tested with besides the scans' (:mod:`.reading_noise`)."""
    if not reading_std:  # not known (setup.json without force_sensor.noise_std_N_Nm), or an older report
        return ""
    return "; plus the F/T readings' noise in the prediction: " + ", ".join(
        f"{c} {s * 1e6:.2f}" for c, s in zip(COMPONENTS, reading_std)
    )


def _scatter_text(scatter: dict | None, alpha: float) -> str:
    """The creep check of the loaded repeats (:mod:`.loaded_scatter`), if the dataset has them."""
    if not scatter:
        return ""
    check = LoadedScatter.from_dict(scatter)
    return ". " + check.sentence(alpha)


def _reachable(val: dict) -> str:
    """What a correct model reaches on the validation tests (noise plus estimation error), if known."""
    before, after = val["before"].get("expected_ratio"), val["after"].get("expected_ratio")
    if before is None or after is None:  # a report written before the expected ratio existed
        return ""
    return (f" A correct model reaches {before:.2f} (the baseline's terms) and {after:.2f} (with the named "
            "terms) on average: the validation scans' noise plus the parameters' estimation error.")  # fmt: skip


def write_report(report: dict, out: Path, joint_names) -> None:
    out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out / "report.json", json.loads(json.dumps(report, default=float)))
    write_text_atomic(out / "report.md", markdown(report, joint_names))
    plot_gap(report, out / "gap.png")
    plot_patterns(report, out / "patterns.png")
    plot_effect(report, out / "effect.png")
