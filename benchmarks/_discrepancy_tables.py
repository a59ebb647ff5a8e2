"""The tables ``bench_discrepancy.py`` prints: scoring each trial, the confusion matrix, the
per-world rates against their theory, the targets, the sizes and the candidates' overlap.

Reads the trials' records (``_discrepancy_worlds.trial``) and the sizes' calibration
(``_discrepancy_sizes.calibrate``); prints markdown to standard output.
"""

from __future__ import annotations

import math
from collections import Counter

import _discrepancy_worlds
import numpy as np
from _discrepancy_worlds import ALPHA, expected_label, scaled, world_key
from scipy.stats import chi2 as chi2_dist
from scipy.stats import ncx2

from vtestbed.researcher.candidates import CANDIDATE_NAMES
from vtestbed.researcher.diagnose import CONFUSABLE_MARGIN, RANK_LABELS
from vtestbed.world.effects import EFFECTS

NEAR_LIMIT_TARGET = 0.80  # issue 11: named correctly at the size detected 80-90 % of the time
COLUMNS = CANDIDATE_NAMES  # the effects the workflow can name
SHORT = {"link_compliance": "link", "joint_coupling": "coupl", "nonlinear_joint": "nonlin",
         "gravity_compensator": "gcomp", "base_compliance": "base", "ft_misalignment": "ftmis",
         "ft_bias_drift": "ftdrift", "block_offset": "block", "scanner_scale": "scale", "nothing": "nothing",
         "two+": "two+", "error": "error"}  # fmt: skip


def outcome(rec: dict) -> str:
    if "error" in rec:
        return "error"
    names = set(rec["names"])
    if not names:
        return "nothing"
    return rec["names"][0] if len(names) == 1 else "two+"


def correct(rec: dict, name: str | None, size: str) -> bool | None:
    if "error" in rec:
        return False
    names = set(rec["names"])
    if name is None:
        return not names
    if name not in COLUMNS:
        return None  # no candidate term: not scored
    if name == "gravity_compensator" and size == "realistic" and not names:
        return True
    return names == {name}


def theory_power(cal: dict, name: str | None, size: str) -> str:
    if name is None:
        return f"{ALPHA * 100:.0f} %"
    c = cal.get(name)
    if c is None:
        return "-"
    if c.get("given") and size == "limit":  # --limit-factor: sized by another test
        return "given"
    if c.get("given"):
        return "-"
    calibrated = c.get("power_realistic" if size == "realistic" else "power_at_limit")
    if calibrated is not None:  # against the estimated floor, as the trials test
        return f"{calibrated * 100:.0f} %"
    lam = c["lambda_realistic"] if size == "realistic" else c["lambda_at_limit"]
    crit = chi2_dist.isf(c["level"], c["df"])
    return f"{ncx2.sf(crit, c['df'], lam) * 100:.0f} % (floor known)"


def fmt_p(p: float) -> str:
    return f"{p:.0e}" if p < 1e-3 else f"{p:.3f}"


def report(worlds, results, cal, overlap, seeds, wall, t_prep) -> None:
    cols = [*COLUMNS, "nothing", "two+"]
    if any(outcome(r) == "error" for rs in results.values() for r in rs):
        cols.append("error")
    print(f"\n## Confusion matrix ({seeds} seeds per world; column = the one effect named, 'two+' = two "
          "different effects named)\n")  # fmt: skip
    print("| hidden effect @ size (factor) | n | " + " | ".join(SHORT.get(c, c) for c in cols) + " |")
    print("| --- | ---: | " + " | ".join("---:" for _ in cols) + " |")
    for name, size, factor in worlds:
        rs = results[world_key(name, size)]
        counts = {c: 0 for c in cols}
        for r in rs:
            counts[outcome(r)] += 1
        label = "clean" if name is None else f"{name} @ {size} (x{factor:.3g})"
        print(
            f"| {label} | {len(rs)} | "
            + " | ".join(str(counts[c]) if counts[c] else "." for c in cols)
            + " |"
        )
    if (
        _discrepancy_worlds.LOADED_REPEATS
    ):  # the creep check's fallback (researcher/scan_mean.py): how often it was taken
        left = sum(r.get("loaded_left_out", False) for rs in results.values() for r in rs)
        total = sum(len(rs) for rs in results.values())
        print(f"\nLoaded repeats left out by the creep check (alpha {ALPHA}): {left} of {total} trials.")

    print("\n## Per world: scoring, detection, validation gap\n")
    print("| world | correct | exact label | theory | detected (p<0.01) | median p "
          "| val. gap before | after | excess removed | correct model | removed of reachable "
          "| id. fit before | after |")  # fmt: skip
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    summary = {}
    for name, size, factor in worlds:
        key = world_key(name, size)
        rs = [r for r in results[key] if "error" not in r]
        n = len(results[key])
        scores = [correct(r, name, size) for r in results[key]]
        acc = None if scores and scores[0] is None else sum(bool(s) for s in scores) / max(n, 1)
        exact = "-"
        if name in COLUMNS:
            want = expected_label(scaled(EFFECTS[name](), factor))
            exact = f"{sum(r['named'][:1] == [want] for r in rs) / max(n, 1) * 100:.0f} %"
        det = sum(r["p_detect"] < ALPHA for r in rs) / max(len(rs), 1)
        vb = np.median([r["val_before"] for r in rs])
        va = np.median([r["val_after"] for r in rs])
        excess = f"{(vb - va) / (vb - 1) * 100:.0f} %" if vb - 1 > 0.05 else "n/a"
        ea = np.median([r.get("val_expected_after", np.nan) for r in rs])
        reachable = f"{(vb - va) / (vb - ea) * 100:.0f} %" if vb - ea > 0.05 else "n/a"
        fb, fa = np.median([r["fit_before"] for r in rs]), np.median([r["fit_after"] for r in rs])
        summary[key] = {
            "accuracy": acc,
            "detected": det,
            "val_before": vb,
            "val_after": va,
            "val_expected_after": ea,
        }
        acc_s = "not scored" if acc is None else f"{acc * 100:.0f} %"
        print(f"| {key} | {acc_s} | {exact} | {theory_power(cal, name, size)} | {det * 100:.0f} % "
              f"| {fmt_p(np.median([r['p_detect'] for r in rs]))} | {vb:.2f} | {va:.2f} | {excess} "
              f"| {ea:.2f} | {reachable} | {fb:.2f} | {fa:.2f} |")  # fmt: skip
    print("\ntheory: the power of the naming test of the effect's own candidate (detection test without a "
          "candidate) for the noise-free effect against the trials' estimated floor (lr_power; 'floor known' where "
          "it is the chi^2 power), an upper bound that ignores the competition between candidates; clean: the "
          "family-wise level. Validation gap: RMS whitened prediction "
          "error of the 5 validation tests over the noise floor, median over the seeds; excess removed = "
          "(before - after) / (before - 1) of the medians. Correct model: the ratio a correct model with the "
          "named terms reaches on average, sqrt(1 + mean leverage) (validation noise plus its parameters' "
          "estimation error; diagnose.expected_validation_ratio); removed of reachable = (before - after) / "
          "(before - correct model).")  # fmt: skip

    print("\n## Labels named (all rounds, counts over the seeds)\n")
    for name, size, _ in worlds:
        rs = results[world_key(name, size)]
        counts = Counter(" + ".join(r["named"]) or "nothing" for r in rs if "error" not in r)
        print(f"- {world_key(name, size)}: " + ", ".join(f"{k} {v}" for k, v in counts.most_common()))
    dropped = {world_key(n, z): Counter(d for r in results[world_key(n, z)] for d in r.get("dropped", ()))
               for n, z, _ in worlds}  # fmt: skip
    print("\nDropped by the backward step (named in a round, redundant once later terms were in): "
          + ("; ".join(f"{k}: " + ", ".join(f"{a} {b}" for a, b in v.most_common()) for k, v in dropped.items() if v)
             or "none"))  # fmt: skip

    print("\n## Misnamed (first round): the winner against the hidden effect's own candidate, medians\n")
    mis = {}
    for name, size, factor in worlds:
        if name not in COLUMNS:
            continue
        want = expected_label(scaled(EFFECTS[name](), factor))
        for r in results[world_key(name, size)]:
            if "error" in r or not r["named"] or r["named"][0] == want:
                continue
            rows = {row["label"]: row for row in r["round1"]}
            win, own = rows[r["named"][0]], rows[want]
            mis.setdefault((world_key(name, size), win["label"], want), []).append(
                (
                    win["lr"],
                    win["df"],
                    own["lr"],
                    own["df"],
                    own["p_value"],
                    own[_discrepancy_worlds.RANK] - win[_discrepancy_worlds.RANK],
                    own["significant"],
                )
            )
    if not mis:
        print("- none")
    for (key, win, want), v in mis.items():
        v = np.array(v)
        print(f"- {key}: {win} named first in {len(v)}: its LR {np.median(v[:, 0]):.1f} (df {v[0, 1]:.0f}); "
              f"{want} LR {np.median(v[:, 2]):.1f} (df {v[0, 3]:.0f}, p {fmt_p(np.median(v[:, 4]))}, "
              f"significant in {int(np.sum(v[:, 6]))}), {RANK_LABELS[_discrepancy_worlds.RANK]} {np.median(v[:, 5]):+.1f} "
              "against the winner")  # fmt: skip

    print(f"\n## Runner-up (first round): the best other significant candidate, {RANK_LABELS[_discrepancy_worlds.RANK]} margin over "
          f"the chosen (< {CONFUSABLE_MARGIN:g}: reported confusable)\n")  # fmt: skip
    for name, size, _ in worlds:
        rs = [r for r in results[world_key(name, size)] if "error" not in r and r["named"]]
        if not rs:
            continue
        ups: dict = {}
        for r in rs:
            ups.setdefault(r["runner_up"] or "none", []).append(r["delta"])
        conf = sum(r["delta"] is not None and r["delta"] < CONFUSABLE_MARGIN for r in rs)
        parts = [
            f"{k} {len(v)}"
            + (f" (median {np.median([x for x in v if x is not None]):.1f})" if k != "none" else "")
            for k, v in sorted(ups.items(), key=lambda x: -len(x[1]))
        ]
        print(
            f"- {world_key(name, size)}: confusable in {conf} of {len(rs)} named; runner-up "
            + ", ".join(parts)
        )

    print("\n## Targets\n")
    clean = results.get("clean", [])  # none with --limit-only
    if clean:
        fa_naming = sum(bool(r.get("names")) or "error" in r for r in clean) / len(clean)
        fa_detect = sum(r.get("p_detect", 0) < ALPHA for r in clean) / len(clean)
        k = round(fa_naming * len(clean))
        upper = clopper_pearson(k, len(clean))[1]
        print(f"- false alarm on the clean world (anything named): {fa_naming * 100:.1f} % ({k} of {len(clean)}; "
              f"95 % upper bound {upper * 100:.1f} %), target <= 1 %; detection test rejects the paper's model on "
              f"{fa_detect * 100:.1f} %")  # fmt: skip
        if line := p_value_calibration(clean):
            print(line)
    for name, size, _ in worlds:
        if name is None or size != "realistic" or name not in COLUMNS:
            continue
        acc = summary[world_key(name, size)]["accuracy"]
        flag = "met" if acc >= 0.95 else "MISSED"
        print(f"- {name} at its realistic size: {acc * 100:.0f} % correct, target >= 95 %: {flag}")
    for name, size, factor in worlds:
        c = cal.get(name)
        if size != "limit" or name not in COLUMNS or c is None or c["power"] < NEAR_LIMIT_TARGET:
            continue
        acc = summary[world_key(name, size)]["accuracy"]
        flag = "met" if acc >= NEAR_LIMIT_TARGET else "MISSED"
        how = "given, --limit-factor" if c.get("given") else f"{c['power'] * 100:.0f} % power in theory"
        print(f"- {name} near its detection limit (x{factor:.3g}, {how}): "
              f"{acc * 100:.0f} % correct, target >= {NEAR_LIMIT_TARGET * 100:.0f} %: {flag}")  # fmt: skip

    if cal:
        print("\n## Sizes near the detection limit (noise-free noncentrality, reference floor)\n")
        print(
            f"| effect | test (df) | lambda at x1 | lambda* ({next(iter(cal.values()))['power'] * 100:.0f} % power) "
            "| f_lim | lambda at f_lim | noise-free best |"
        )
        print("| --- | --- | ---: | ---: | ---: | ---: | --- |")
        for c in cal.values():
            if c.get("given"):
                print(f"| {c['name']} | {c['test']} | - | - | {c['factor']:.3g} | - | - |")
                continue
            cap = ""
            if c["capped"]:
                bound = "scans fail" if math.isfinite(c["f_fail"]) else "parameter range"
                cap = f" (capped: {bound} above x{min(c['f_fail'], c['f_range']):.3g})"
            print(f"| {c['name']} | {c['test']} ({c['df']}) | {c['lambda_realistic']:.3g} | {c['target']:.1f} "
                  f"| {c['factor']:.3g}{cap} | {c['lambda_at_limit']:.3g} | {c['label'] or '-'} |")  # fmt: skip
    if overlap:
        print("\n## Candidate overlap (clean world, noise-free, whitened; stiffness columns projected out)\n")
        print("R^2 of each candidate on the stiffness columns (>= 0.999 is reported 'absorbed'):")
        print("  " + ", ".join(f"{k} {v:.4f}" for k, v in sorted(overlap["r2"].items(), key=lambda x: -x[1])))
        top = sorted(overlap["pairs"].items(), key=lambda x: -x[1])[:8]
        print("largest canonical correlation between two candidates (1 = interchangeable):")
        for (a, b), v in top:
            print(f"  {v:.4f}  {a} ~ {b}")

    times = [r["time"] for rs in results.values() for r in rs if "time" in r]
    if times:
        tot = np.array([t["total"] for t in times])
        parts = {k: np.mean([t[k] for t in times]) for k in ("measure", "floor", "diagnose")}
        print(f"\n## Cost\n\n- per trial (one worker, one core): {tot.mean():.2f} s mean ({tot.min():.2f}-{tot.max():.2f}): "
              f"reduce 25 tests {parts['measure']:.2f} s, noise floor from {25 * _discrepancy_worlds.REPEATS} repeat scans {parts['floor']:.2f} s, "
              f"name + validation gap {parts['diagnose']:.3f} s")  # fmt: skip
        print(f"- {len(times)} trials in {wall:.0f} s wall ({wall / len(times):.2f} s per trial on the pool); "
              f"physics (prepare) {t_prep:.0f} s of worker time in total")  # fmt: skip


def p_value_calibration(clean: list[dict]) -> str:
    """One line on the clean worlds' first-round p-values: under a right model each candidate's is
    uniform, so its share below a level is that level (the binomial std beside it), its mean
    likelihood ratio is its df, and Bonferroni's family-wise rate is at most alpha. Far more p-values
    than false alarms: this resolves the naming's level where 400 trials' few false names cannot."""
    rounds = [r["round1"] for r in clean if r.get("round1")]
    if not rounds:
        return ""
    p = np.array([c["p_value"] for rnd in rounds for c in rnd])
    ratio: dict[str, list[float]] = {}
    for rnd in rounds:
        for c in rnd:
            ratio.setdefault(c["label"], []).append(c["lr"] / c["df"])
    means = [np.mean(v) for v in ratio.values()]
    adjusted = np.array([min(1.0, min(c["p_value"] for c in rnd) * len(rnd)) for rnd in rounds])

    def share(level):
        return f"{np.mean(p < level) * 100:.2f} % (+-{np.sqrt(level * (1 - level) / p.size) * 100:.2f})"

    return (
        f"- calibration, the clean worlds' {p.size} first-round p-values ({len(ratio)} candidates): below 0.01 "
        f"{share(0.01)}, below 0.05 {share(0.05)}; mean likelihood ratio / df per candidate "
        f"{min(means):.2f}-{max(means):.2f}; Bonferroni-adjusted smallest p below 0.05 in "
        f"{np.mean(adjusted < 0.05) * 100:.1f} %, below 0.1 in {np.mean(adjusted < 0.1) * 100:.1f} % of the worlds"
    )


def clopper_pearson(k: int, n: int) -> tuple[float, float]:
    """95 % Clopper-Pearson interval of a binomial rate with k of n (bench_two_effects uses it too)."""
    from scipy.stats import beta

    lo = 0.0 if k == 0 else float(beta.ppf(0.025, k, n - k + 1))
    hi = 1.0 if k >= n else float(beta.ppf(0.975, k + 1, n - k))
    return lo, hi
