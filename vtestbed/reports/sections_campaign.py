"""The sections of a campaign's report (``vtestbed sweep``: ``campaign.json`` and the Parquet trials).

The numbers come from :mod:`vtestbed.campaigns.report` run on the trials in the store (computed
once per report and kept in ``folder.extra``); errors are relative, ``e = k/k_true - 1``, in %.
"""

from __future__ import annotations

from .blocks import Figure, KeyValues, Num, Section, Table, Text, versions
from .figures import campaign as campaign_summary
from .loader import ResultFolder
from .sections_run import measured_from

AXES = ("pose_set", "n_tests", "scanner_noise_scale", "ft_noise_scale", "method")


def _computed(folder: ResultFolder):
    if "campaign" not in folder.extra:
        folder.extra["campaign"] = campaign_summary(folder.trials, folder.data)
    return folder.extra["campaign"]


def _swept(summary) -> list[str]:
    return [a for a in AXES if summary[a].nunique() > 1] or ["pose_set"]


def campaign(folder: ResultFolder) -> Section:
    m, df = folder.data, folder.trials
    c = m["campaign"]
    axes = "; ".join(f"{k} = {', '.join(str(v) for v in vals)}" for k, vals in c.get("axes", {}).items())
    items = [("scenario", m["scenario"]), ("seed", str(c.get("seed"))), ("trials per cell", str(c.get("trials"))),
             ("paired (common random numbers)", str(c.get("paired"))), ("axes", axes or "none"),
             ("displacements measured from", measured_from(m.get("reference"))),
             ("cells", str(df["cell_key"].nunique())), ("trials on disk", str(len(df))),
             ("failed trials", str(int((df["status"] != "ok").sum())))]  # fmt: skip
    return Section("campaign", "Campaign", [KeyValues(items, id="campaign-facts")])


def summary_table(folder: ResultFolder) -> Section:
    """Per cell: each joint's RMS relative error, and the spread against the predicted std."""
    _, summary, _ = _computed(folder)
    swept = _swept(summary)
    joints = list(dict.fromkeys(summary["joint"]))
    rows = []
    for key, g in summary.groupby(swept, sort=True):
        key = key if isinstance(key, tuple) else (key,)
        g = g.set_index("joint")
        rows.append([*(str(k) for k in key), str(int(g["trials"].iloc[0])),
                     *[Num(g.loc[j, "rms_pct"], ".3g") for j in joints],
                     *[Num(g.loc[j, "ratio"], ".2f") for j in joints]])  # fmt: skip
    cols = [*swept, "trials", *[f"RMS {j} [%]" for j in joints], *[f"spread/pred {j}" for j in joints]]
    note = Text(["RMS = sqrt(mean e^2) over a cell's trials (bias and spread together); spread/pred = std of e "
                 "over the trials divided by the identification's own std(k)/k_true (1 when it is honest)."])  # fmt: skip
    return Section("summary", "Summary per cell", [note, Table(cols, rows, id="campaign-summary")])


def trends(folder: ResultFolder) -> Section | None:
    report, _, figs = _computed(folder)
    blocks = []
    for axis, t in report["trends"].items():
        word = "grows" if axis != "n_tests" else "shrinks"
        blocks.append(
            Text(
                [f"RMS error {word} along {axis} in {t['monotonic']} of {t['slices']} (cell, joint) slices."]
            )
        )
    for name, caption in (("error_vs_noise", "Error against the scanner noise scale (solid: median |e|, dashed: spread)"),
                          ("error_vs_tests", "Error against the number of tests (solid: median |e|, dashed: spread)")):  # fmt: skip
        if name in figs:
            blocks.append(Figure(figs[name], caption, f"fig-{name.replace('_', '-')}"))
    return Section("trends", "Error against noise and test count", blocks) if blocks else None


def spread(folder: ResultFolder) -> Section:
    report, _, figs = _computed(folder)
    s = report["spread_check"]
    rows = [[str(n), str(b["cells"]), str(b["inside"]), Num(b["ratio_median"], ".2f")]
            for n, b in s["by_n_tests"].items()]  # fmt: skip
    text = Text([f"Spread over the trials against the predicted std: {s['inside']} of {s['cells']} (cell, joint) "
                 f"within x{s['factor']:g}; median ratio {s['ratio_median']:.2f} "
                 f"(range {s['ratio_min']:.2f}..{s['ratio_max']:.2f})."])  # fmt: skip
    blocks = [
        text,
        Table(
            ["tests", "(cell, joint)", f"within x{s['factor']:g}", "median ratio"], rows, id="spread-check"
        ),
    ]
    blocks.append(
        Figure(
            figs["spread_vs_predicted"],
            "Spread against predicted std, one point per (cell, joint)",
            "fig-spread",
        )
    )
    return Section("spread", "Spread against predicted std", blocks)


def pose_choice(folder: ResultFolder) -> Section:
    report, _, figs = _computed(folder)
    choice = report["pose_choice"]
    if not choice:
        return Section("pose-choice", "Pose choice", [Text(["The campaign has no kappa_regions pose set: "
                                                            "nothing to compare the pose choice with."])])  # fmt: skip
    rows = [[str(r["n_tests"]), r["pose_set"], str(r["trials"]), Num(r["score_pct"], ".3f"),
             Num(r["ratio_to_kappa"], ".3f"), Num(r["ratio_lo95"], ".3f"), Num(r["ratio_hi95"], ".3f"), r["verdict"]]
            for r in choice]  # fmt: skip
    cols = ["tests", "pose set", "trials", "score [%]", "ratio to kappa", "95 % low", "95 % high", "verdict"]
    text = Text(["Error score = geometric mean over the joints of the RMS error at the reference noise; ratio to "
                 "kappa_regions with a paired bootstrap 95 % interval (below 1: the other set is better)."])  # fmt: skip
    blocks = [text, Table(cols, rows, id="pose-choice")]
    if "pose_choice_png" in figs:
        blocks.append(Figure(figs["pose_choice_png"], "Error score relative to kappa_regions, 95 % bootstrap intervals",
                             "fig-pose-choice"))  # fmt: skip
    return Section("pose-choice", "Pose choice", blocks)


def details(folder: ResultFolder) -> Section:
    m = folder.data
    items = [("campaign fingerprint", str(m.get("fingerprint"))), ("code fingerprint", str(m.get("code_fingerprint"))),
             ("seed", str(m["campaign"].get("seed")))]  # fmt: skip
    return Section(
        "details", "Versions and seed", [KeyValues(items + versions(m, "campaign.json"), id="versions")]
    )


SECTIONS = [campaign, summary_table, trends, spread, pose_choice, details]
