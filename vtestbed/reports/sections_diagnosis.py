"""The sections of a diagnosis's report (``vtestbed diagnose --out``: ``report.json``).

Stiffness in N*mm/rad, the noise floor in um and urad, residuals as ratios to the noise floor.
"""

from __future__ import annotations

from ..researcher.block_size import NOT_CHECKED, ScaleCheck
from ..researcher.diagnose import confusable_margin, rank_label
from ..researcher.discrepancy import COMPONENTS, detection_alone, no_candidates_text, stand_ins
from ..researcher.loaded_scatter import LoadedScatter
from ..researcher.scale_term import named_note, report_scale
from . import figures
from .blocks import Figure, KeyValues, Num, Plot3D, Section, Table, Text, versions
from .loader import ResultFolder


def noise_floor(folder: ResultFolder) -> Section:
    r = folder.data
    nf = r["noise_floor"]
    rows = [[c, Num(s, ".3f", 1e6), Num(n, ".3f")]
            for c, s, n in zip(COMPONENTS, nf["component_std"], r["detect"]["normalised_residual_rms"])]  # fmt: skip
    facts = KeyValues([("dataset", r["dataset"]), ("statics of the baseline", r["statics"]),
                       ("alpha (family-wise)", Num(r["alpha"], "g")),
                       ("repeat-scan samples", str(nf["n_samples"])),
                       ("unloaded scans averaged per displacement", str(nf.get("reference_scans", 1))),
                       ("loaded scans averaged per displacement", str(nf.get("loaded_scans", 1)))],
                      id="diagnosis-facts")  # fmt: skip
    table = Table(["component", "noise floor std [um | urad]", "baseline residual RMS / floor"], rows,
                  id="noise-floor")  # fmt: skip
    blocks = [facts, table]
    if reading := nf.get(
        "reading_std"
    ):  # the F/T readings' noise in the prediction (researcher/reading_noise.py)
        blocks.append(Text(["The model is tested against the floor plus the F/T readings' noise in its prediction, std "
                            + ", ".join(f"{c} {s * 1e6:.3f}" for c, s in zip(COMPONENTS, reading))
                            + " (um, urad): one reading at each end of a test, which repeat scans do not average."],
                           id="reading-noise"))  # fmt: skip
    if scatter := nf.get("loaded_scatter"):  # the loaded repeats' creep check (researcher/loaded_scatter.py)
        check = LoadedScatter.from_dict(scatter)
        blocks.append(Text([check.sentence(r["alpha"])], id="loaded-scatter"))
    # the block's size as a length standard (researcher/block_size.py), and what the naming made of
    # it (researcher/scale_term.py; older reports have no scale_term)
    settled = [term.sentence()] if (term := report_scale(r)) else []
    if scale := r.get("scale_check"):
        blocks.append(Text([ScaleCheck.from_dict(scale).sentence(), *settled], id="scale-check"))
    elif "scale_check" in r:  # not checked (a mesh target, too few tests); reports before 2026-11-29: no key
        blocks.append(Text([NOT_CHECKED, *settled], id="scale-check"))
    return Section("noise-floor", "Noise floor", blocks)


def detection(folder: ResultFolder) -> Section:
    d = folder.data["detect"]
    verdict = "rejected" if d["model_rejected"] else "consistent with the noise"
    facts = KeyValues([("chi^2", Num(d["chi2"], ".1f")), ("degrees of freedom", str(d["dof"])),
                       ("p-value", Num(d["p_value"], ".3g")), ("the paper's model", verdict)], id="detection")  # fmt: skip
    pats = sorted(
        ((n, v) for n, v in d["patterns"].items() if v["rho"] is not None), key=lambda kv: kv[1]["p_value"]
    )
    rows = [[n, Num(v["rho"], "+.2f"), Num(v["p_value"], ".2g")] for n, v in pats]
    blocks = [facts, Table(["pose feature", "Spearman rho", "p-value"], rows, id="patterns",
                           caption="Per-test residual against the pose features, strongest first")]  # fmt: skip
    fig = figures.patterns(folder.data)
    if fig:
        blocks.append(Figure(fig, "Per-test residual against the pose and the load", "fig-patterns"))
    return Section("detection", "Detection", blocks)


def candidates(folder: ResultFolder) -> Section:
    """Every round's candidate tests: likelihood ratio, p-value, held-out error, BIC, significance."""
    blocks = []
    if detection_alone(folder.data):
        blocks.append(Text([no_candidates_text()], id="no-candidates"))
    for i, rnd in enumerate(folder.data["rounds"], start=1):
        base = ", ".join(rnd["base"]) or "the paper's model"
        rows = [[t["label"], Num(t["lr"], ".2f"), str(t["df"]), Num(t["p_value"], ".3g"), Num(t.get("press"), ".2f"),
                 Num(t["bic"], ".2f"),
                 "yes" if t["significant"] else "no",
                 "-" if t.get("overlap") is None else Num(t["overlap"], ".2f")] for t in rnd["tests"]]  # fmt: skip
        header = ["candidate", "likelihood ratio", "parameters", "p-value", "held-out error", "BIC", "significant",
                  f"share of {rnd.get('overlap_of') or 'the chosen term'}'s pattern"]  # fmt: skip
        if any("runner_overlap" in t for t in rnd["tests"]):  # a confusable round (since 2026-11-29)
            header.append(f"share of {rnd['runner_up']}'s pattern")
            for row, t in zip(rows, rnd["tests"], strict=True):
                row.append("-" if t.get("runner_overlap") is None else Num(t["runner_overlap"], ".2f"))
        caption = (f"Round {i}: candidates added to {base} (chi^2 {rnd['base_chi2']:.1f}); chosen: {rnd['chosen'] or 'nothing'}"
                   f" (ranked by {rank_label(folder.data)})")  # fmt: skip
        if rnd.get("dropped"):  # the stepwise search's re-test after this round's addition
            caption += f"; dropped: {', '.join(d['label'] for d in rnd['dropped'])}"
        blocks.append(Table(header, rows, id=f"candidates-round-{i}", caption=caption))
    return Section("candidates", "Candidate terms", blocks)


def named(folder: ResultFolder) -> Section:
    """The named effects, their parameters with std, and the stiffness before and after."""
    r = folder.data
    text = (
        [no_candidates_text()]
        if detection_alone(r)
        else [f"Named: {', '.join(n + named_note(r, n) for n in r['named']) or 'nothing'}."]
    )
    text += [f"{label}: {note}" for label, note in r["absorbed"].items()]
    text += [f"{label} (dropped): {note}" for label, note in r.get("dropped", {}).items()]  # stepwise search
    text += [
        f"{c['chosen']} could also be {c['runner_up']} ({confusable_margin(r, c)})" for c in r["confusable"]
    ]
    text += [
        f"{chosen}'s pattern is also reproduced by "
        + ", ".join(f"{label} ({share:.0%})" for label, share in alike)
        + ": it may stand for one of them (discover --always tests them against each other)"
        for chosen, alike in stand_ins(r).items()
    ]
    rows = []
    for label, params in r["model"]["parameters"].items():
        stds = r["model"]["parameters_std"][label]
        rows += [[label, p, Num(v, ".4g"), Num(stds[p], ".2g")] for p, v in params.items()]
    before, after = r["baseline"], r["model"]
    k_rows = [[f"joint{i + 1}", Num(k0, ".4e", 1e3), Num(s0, ".2e", 1e3), Num(k1, ".4e", 1e3), Num(s1, ".2e", 1e3)]
              for i, (k0, s0, k1, s1) in enumerate(zip(before["stiffness_Nm_per_rad"], before["stiffness_std_Nm_per_rad"],
                                                       after["stiffness_Nm_per_rad"], after["stiffness_std_Nm_per_rad"]))]  # fmt: skip
    return Section("named", "Named effects", [
        Text(text), Table(["term", "parameter", "value", "std"], rows, id="named-parameters"),
        Table(["joint", "k before [N*mm/rad]", "std before", "k after [N*mm/rad]", "std after"], k_rows,
              id="stiffness-before-after")])  # fmt: skip


def gap(folder: ResultFolder) -> Section:
    r = folder.data
    fit, val = r["identification_fit"], r["validation"]
    rows = [["identification residual / floor", Num(fit["before"], ".3f"), Num(fit["after"], ".3f")]]
    if val["before"]:
        rows.append(["validation prediction error / floor", Num(val["before"]["ratio_to_floor"], ".3f"),
                     Num(val["after"]["ratio_to_floor"], ".3f")])  # fmt: skip
        if "expected_ratio" in val["before"]:  # older reports lack it
            rows.append(["a correct model's validation error / floor (mean)", Num(val["before"]["expected_ratio"], ".3f"),
                         Num(val["after"]["expected_ratio"], ".3f")])  # fmt: skip
    parts = [Table(["", "before", "after"], rows, id="gap-table"),
             Figure(figures.gap(r), "Per-test RMS whitened residual before and after the named terms", "fig-gap")]  # fmt: skip
    effect = figures.effect(r)
    if effect is not None:
        share = r["effect"]["explained_fraction"]
        parts.append(Figure(effect, f"The named effect: the baseline's whitened residual against what the named "
                                    f"terms explain ({share:.0%} of its chi^2)", "fig-effect"))  # fmt: skip
    return Section("gap", "The gap before and after", parts)


def scene(folder: ResultFolder) -> Section | None:
    from .scene import one_test_scene

    if folder.dataset is None:
        return None
    view = one_test_scene(folder.dataset)
    caption = (f"Test {view['test_id']} of {folder.dataset}: robot (nominal, commanded), block (fitted), wire "
               f"({view['hook']}, measured force), clouds ({view['points'][0]} and {view['points'][1]} points) and fitted faces.")  # fmt: skip
    return Section("scene", "3-D view of one test", [Plot3D(view["figure_json"], caption, "scene-3d")])


def details(folder: ResultFolder) -> Section:
    return Section("details", "Versions", [KeyValues(versions(folder.data, "report.json"), id="versions")])


SECTIONS = [noise_floor, detection, candidates, named, gap, scene, details]
