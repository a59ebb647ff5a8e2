"""docs/errors.md's bad-input tables as a whole (issue 13): every table is checked by one of the
tests/test_errors_table_*.py modules, the ids are unique, the count the page states is the number
of rows, and the placeholders of a documented message match what they stand for and nothing else."""

from __future__ import annotations

import re

import test_errors_table_cli
import test_errors_table_dataset
import test_errors_table_results
import test_errors_table_scenario
from errors_table import DOC, pattern, read_rows

MODULES = (
    test_errors_table_cli,
    test_errors_table_dataset,
    test_errors_table_results,
    test_errors_table_scenario,
)


def test_every_table_is_checked_and_the_ids_are_unique():
    rows = read_rows()
    keys = [r.key for r in rows]
    assert len(keys) == len(set(keys)), sorted(k for k in keys if keys.count(k) > 1)
    checked = {key for m in MODULES for key in m.ROWS}
    assert {r.key for r in rows} == checked, "a table under a heading that no test module reads"
    cases = [key for m in MODULES for key in m.CASES]
    assert len(cases) == len(set(cases)) and set(cases) == set(keys)


def test_the_stated_count_is_the_number_of_rows():
    stated = re.search(r"\*\*(\d+) bad inputs\*\*", DOC.read_text(encoding="utf-8"))
    assert stated, "docs/errors.md must state the number of rows as **N bad inputs**"
    assert int(stated.group(1)) == len(read_rows()) >= 51


def test_placeholders_are_wildcards_and_the_rest_is_exact():
    p = pattern("DIR/tests.csv line N: byte N of the force sensor [0, 100] N, got [...]")
    assert p.fullmatch("/tmp/x y/tests.csv line 3: byte 2362 of the force sensor [0, 100] N, got [1, nan]")
    assert not p.fullmatch("/tmp/tests.csv line 3: byte 2362 of the force sensor [0, 100] N, got [1, nan]!")
    assert not p.fullmatch("/tmp/tests.csv line x: byte 1 of the force sensor [0, 100] N, got []")
    assert not p.fullmatch("/tmp/tests.csv line 3: byte 1 of the force sensor [0, 10] N, got []")
    assert pattern("range_N_Nm (Fx..Tz) N*m").fullmatch("range_N_Nm (Fx..Tz) N*m")
    assert not pattern("range_N_Nm").fullmatch("range_5_Nm")


def test_rows_are_read_from_id_tables_only(tmp_path):
    doc = tmp_path / "errors.md"
    doc.write_text(
        "## One\n\n| id | bad input | message |\n| --- | --- | --- |\n"
        "| a-1 | `x \\| y` | `FILE: \\|theta5\\| of at least 1 deg` (note) |\n\n"
        "## Two\n\n| input | what happens |\n| --- | --- |\n| b | `c` |\n"
    )
    (row,) = read_rows(doc)
    assert (row.key, row.section, row.bad_input) == ("a-1", "One", "`x | y`")
    assert row.message == "FILE: |theta5| of at least 1 deg"
