"""The discovery page's sections, from ``discover.json`` (``vtestbed discover SCENARIO --out DIR``).

What was named before and after each round of discrimination tests, each round's rivals and its
proposed tests (joint angles in degrees, tensions in N), the separation of the rivals predicted
(smallest T over the rival pairs, in noise-floor units) and measured (the best rival's BIC lead),
and the validation tests' prediction error over the noise floor at every stage (1 = as good as
the noise). Each stage's full diagnosis is a diagnosis folder of its own
(``DIR/round<k>/diagnose``, round 0 the scenario's tests alone), with its own page.
"""

from __future__ import annotations

from ..design.rivals import ROUND_KINDS
from ..researcher.diagnose import rank_label
from . import figures
from .blocks import Figure, KeyValues, Num, Section, Table, Text, versions
from .loader import DIAGNOSIS_FILE, ResultFolder


def _names(labels) -> str:
    return ", ".join(labels) if labels else "nothing"


def _lead(measured: dict) -> str:
    """The best rival and its BIC lead (none with a single rival)."""
    delta = measured.get("delta_bic")
    return measured["best"] if delta is None else f"{measured['best']} by {delta:.1f}"


def gap_stages(result: dict) -> list[tuple[str, float, float]]:
    """``(stage, paper's model, named terms)``: the validation error over the floor at each stage,
    the scenario's tests first, then after each round; empty without validation tests."""
    before = result.get("validation_gap_before")
    if not before:
        return []
    stages = [("the scenario's tests", before["baseline"], before["named"])]
    for rnd in result["rounds"]:
        if rnd.get("validation_gap"):
            stages.append(
                (
                    f"after round {rnd['round']}",
                    rnd["validation_gap"]["baseline"],
                    rnd["validation_gap"]["named"],
                )
            )
    return stages


def summary(folder: ResultFolder) -> Section:
    r = folder.data
    rounds = r["rounds"]
    items = [
        ("scenario", r["scenario"]),
        ("seed", str(r["seed"])),
        ("alpha of the first diagnosis", Num(r["alpha"], "g")),
    ]
    if rounds and r.get("alpha_after_round") is not None:  # discover.json before 2026-11-28: none
        items.append(("alpha after a round", Num(r["alpha_after_round"], "g")))
    items += [("candidates ranked by", rank_label(r)),  # discover.json before 2026-11-26: BIC
              ("named before", _names(r["named_before"])),
              ("rounds of discrimination tests", str(len(rounds))),
              ("extra tests", str(sum(len(k["proposal"]["tests"]) for k in rounds)))]  # fmt: skip
    if rounds:
        items.append(("named after", _names(r["named_after"])))
    text = [f"Before: {c['chosen']} could also be {c['runner_up']}." for c in r.get("confusable_before", [])]
    text += [f"After: still {c['chosen']} or {c['runner_up']}." for c in r.get("confusable_after") or []]
    if not rounds:
        text.append(r.get("note") or "No round of discrimination tests was run.")
    blocks = [KeyValues(items, id="discover-summary")]
    if text:
        blocks.append(Text(text, id="discover-confusable"))
    return Section("summary", "Names before and after", blocks)


def rounds(folder: ResultFolder) -> Section | None:
    r = folder.data
    if not r["rounds"]:
        return None
    rows = []
    for k in r["rounds"]:
        p, mb, ma = k["proposal"], k["measured_before"], k["measured_after"]
        rows.append([str(k["round"]), ROUND_KINDS.get(k["rivals"]["reason"], k["rivals"]["reason"]),
                     _names(k["rivals"]["rivals"]), _names(k["rivals"]["base_terms"]), str(len(p["tests"])),
                     Num(p["separation_before"], ".1f"), Num(p["separation_after"], ".1f"),
                     _lead(mb), _lead(ma),
                     _names(k["named"])])  # fmt: skip
    columns = ["round", "why", "rivals", "on top of", "tests", "predicted T before", "predicted T after",
               "measured: best rival by BIC, before", "after", "named after the round"]  # fmt: skip
    caption = ("T: the smallest noncentrality over the rival pairs, noise-floor units (T = 25 tests one "
               "parameter at 0.1 % with 95 % power); the measured lead is the best rival's BIC margin")  # fmt: skip
    return Section(
        "rounds",
        "Rounds of discrimination tests",
        [Table(columns, rows, id="discover-rounds", caption=caption)],
    )


def proposed(folder: ResultFolder) -> Section | None:
    blocks = []
    for k in folder.data["rounds"]:
        tests = k["proposal"]["tests"]
        rows = [[str(i), *(Num(q, ".1f") for q in t["q_deg"]), t["hook"], t["anchor"], Num(t["tension_N"], ".0f")]
                for i, t in enumerate(tests, start=1)]  # fmt: skip
        n = len(tests[0]["q_deg"]) if tests else 6
        columns = ["test", *(f"A{j} [deg]" for j in range(1, n + 1)), "hook", "ring", "tension [N]"]
        blocks.append(Table(columns, rows, id=f"proposed-round-{k['round']}",
                            caption=f"Round {k['round']}: the tests proposed (and run in the same world)"))  # fmt: skip
    return Section("proposed", "The proposed tests", blocks) if blocks else None


def gap(folder: ResultFolder) -> Section | None:
    stages = gap_stages(folder.data)
    if not stages:
        return None
    rows = [[stage, Num(paper, ".3f"), Num(named, ".3f")] for stage, paper, named in stages]
    table = Table(["stage", "paper's model", "with the named terms"], rows, id="discover-gap",
                  caption="Validation prediction error over the noise floor (1 = as good as the noise)")  # fmt: skip
    fig = Figure(figures.discovery_gap(stages), "The gap at each stage: the paper's model and the named terms, "
                 "validation prediction error over the noise floor", "fig-discover-gap")  # fmt: skip
    return Section("gap", "The gap shrinking", [table, fig])


def diagnoses(folder: ResultFolder) -> Section:
    rows = []
    for k in range(len(folder.data["rounds"]) + 1):
        path = folder.root / f"round{k}" / "diagnose"
        if not (path / DIAGNOSIS_FILE).is_file():
            continue
        page = path / "report.html"
        rows.append([str(k), str(path), str(page) if page.is_file() else f"vtestbed report {path}"])
    if not rows:
        text = [f"No round folder with a diagnosis is beside discover.json in {folder.root}."]
        return Section("diagnoses", "Each stage's diagnosis", [Text(text, id="discover-diagnoses")])
    table = Table(["round", "diagnosis folder", "its page"], rows, id="discover-diagnoses",
                  caption="Round 0: the scenario's tests alone; round k: with the tests of rounds 1 to k")  # fmt: skip
    return Section("diagnoses", "Each stage's diagnosis", [table])


def details(folder: ResultFolder) -> Section:
    return Section("details", "Versions", [KeyValues(versions(folder.data, "discover.json"), id="versions")])


SECTIONS = [summary, rounds, proposed, gap, diagnoses, details]
