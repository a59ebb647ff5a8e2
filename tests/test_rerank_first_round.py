"""The offline verdict of a first naming round (benchmarks/rerank_first_round.py), checked on
hand-made rounds against the definitions of ``design.rivals.rivals_from_report``.

Two candidates, so the round's level is ``alpha / 2 = 0.005`` at ``alpha = 0.01``: a name is
*weak* when its p-value is above ``level / MARGINAL_FACTOR = 5e-4``, a candidate is *plausible*
below ``MARGINAL_FACTOR * level = 0.05``, and a runner-up within ``CONFUSABLE_MARGIN = 10`` of the
chosen term's held-out error makes the round confusable.
"""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from vtestbed.design.rivals import MARGINAL_FACTOR
from vtestbed.researcher.diagnose import CONFUSABLE_MARGIN

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import rerank_first_round as rerank  # noqa: E402

ALPHA = 0.01
LEVEL = ALPHA / 2


def row(label: str, name: str, p_value: float, press: float, bic: float = 150.0, df: int = 1) -> dict:
    return {"label": label, "name": name, "lr": 0.0, "df": df, "p_value": p_value, "bic": bic,
            "press": press, "significant": p_value < LEVEL}  # fmt: skip


def test_the_constants_the_cases_are_built_on():
    assert (LEVEL / MARGINAL_FACTOR, MARGINAL_FACTOR * LEVEL, CONFUSABLE_MARGIN) == pytest.approx(
        (5e-4, 0.05, 10.0)
    )


@pytest.mark.parametrize(
    ("rows", "want", "verdict"),
    [
        # a strong name, the other candidate far from the level: decided, right or wrong
        ([row("link_compliance(link 2)", "link_compliance", 1e-8, 100.0), row("block_offset", "block_offset", 0.5, 140.0)],
         "link_compliance", "right, decided"),
        ([row("link_compliance(link 2)", "link_compliance", 1e-8, 100.0), row("block_offset", "block_offset", 0.5, 140.0)],
         "block_offset", "wrong, decided"),
        # the held-out error ranks, not BIC: block_offset has the lower BIC and is not chosen
        ([row("link_compliance(link 2)", "link_compliance", 1e-8, 100.0, bic=160.0),
          row("block_offset", "block_offset", 1e-9, 100.0 + CONFUSABLE_MARGIN + 1, bic=140.0)],
         "link_compliance", "right, decided"),
        # the runner-up within the margin: confusable
        ([row("link_compliance(link 2)", "link_compliance", 1e-8, 100.0),
          row("block_offset", "block_offset", 1e-9, 100.0 + CONFUSABLE_MARGIN - 1)],
         "block_offset", "wrong, undecided"),
        # a weak name (p between level / 10 and level): marginal
        ([row("link_compliance(link 2)", "link_compliance", 1e-3, 100.0), row("block_offset", "block_offset", 0.5, 140.0)],
         "link_compliance", "right, undecided"),
        # nothing named, a candidate below 10 x level: marginal; above it: decided
        ([row("link_compliance(link 2)", "link_compliance", 0.02, 100.0), row("block_offset", "block_offset", 0.5, 140.0)],
         "link_compliance", "nothing, undecided"),
        ([row("link_compliance(link 2)", "link_compliance", 0.2, 100.0), row("block_offset", "block_offset", 0.5, 140.0)],
         None, "nothing, decided"),
    ],
)  # fmt: skip
def test_verdict_follows_the_rivals_rules(rows, want, verdict):
    assert rerank.verdict(rows, want, ALPHA) == verdict


def test_the_script_tallies_a_record_and_refuses_a_bad_one(tmp_path):
    strong = [
        row("link_compliance(link 2)", "link_compliance", 1e-8, 100.0),
        row("block_offset", "block_offset", 0.5, 140.0),
    ]
    weak = [
        row("link_compliance(link 2)", "link_compliance", 0.02, 100.0),
        row("block_offset", "block_offset", 0.5, 140.0),
    ]
    trials = [{"seed": 1, "chi2": 150.0, "round1": strong}, {"seed": 2, "chi2": 150.0, "round1": weak},
              {"seed": 3, "error": "ValueError: a failed trial is not scored"}]  # fmt: skip
    record = tmp_path / "near.json"
    record.write_text(json.dumps({"results": {"link_compliance @ limit": trials}}))
    script = Path(rerank.__file__)
    out = subprocess.run(
        [sys.executable, str(script), str(record)], capture_output=True, text=True, check=True
    )
    line = next(x for x in out.stdout.splitlines()[::-1] if x.startswith("link_compliance @ limit"))
    assert [int(v) for v in line.split()[-len(rerank.VERDICTS) :]] == [1, 0, 0, 0, 1, 0]
    (bad := tmp_path / "bad.json").write_text("[1, 2]")
    out = subprocess.run([sys.executable, str(script), str(bad)], capture_output=True, text=True)
    assert out.returncode == 2 and "bad.json" in out.stderr and "Traceback" not in out.stderr


def test_the_ceiling_counts_the_hidden_effect_among_the_significant_whatever_its_rank():
    """A hidden link that every rule ranks second (a lower held-out error, BIC, AIC and p-value for
    the rival) is still within reach; a trial with nothing significant is not, and on a clean world it
    is the right outcome."""
    second = [
        {**row("link_compliance(link 2)", "link_compliance", 1e-6, 120.0, bic=150.0), "lr": 30.0},
        {**row("block_offset", "block_offset", 1e-9, 100.0, bic=140.0), "lr": 40.0},
    ]
    none = [
        row("link_compliance(link 2)", "link_compliance", 0.2, 100.0),
        row("block_offset", "block_offset", 0.5, 140.0),
    ]
    results = {
        "link_compliance @ limit": [{"chi2": 150.0, "round1": second}, {"chi2": 150.0, "round1": none}],
        "clean": [{"chi2": 150.0, "round1": none}, {"chi2": 150.0, "round1": second}],
    }
    lines = rerank.tally(results)
    counts = {ln.split()[0]: [int(v) for v in ln.split() if v.isdigit()] for ln in lines[1:]}
    # the rules' picks: block_offset in the first trial, nothing in the second
    assert counts["link_compliance"] == [0] * len(rerank.RULES) + [1, 2]
    assert counts["clean"] == [1] * len(rerank.RULES) + [1, 2]
    assert counts["total"] == [1] * len(rerank.RULES) + [2]  # no trial count in the total row
