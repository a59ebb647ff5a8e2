"""The file validators: boundaries of every check, and errors naming the file, the dotted field
and the valid range or names."""

import math

import pytest

from vtestbed.errors import ScenarioError
from vtestbed.schema import Fields

F = Fields("s.toml")


def test_numbers_inside_the_closed_range_are_accepted_as_floats():
    for value in (0.1, 0, 1.25, 1):
        got = Fields().number(value, "x", 0.0, 1.25)
        assert isinstance(got, float) and got == value
    assert F.vector([1, 2.5, 3], "v", 3, 1.0, 3.0) == (1.0, 2.5, 3.0)
    assert F.integer(500, "n", 2, 500) == 500 and F.seed(0, "seed") == 0


@pytest.mark.parametrize(
    "value, message",
    [
        (1.2500001, r"s\.toml: a\.b: = 1\.25 is outside the valid range \[0\.1, 1\.25\]"),
        (0.0999, r"s\.toml: a\.b: = 0\.0999 is outside the valid range \[0\.1, 1\.25\]"),
        (math.nan, r"a\.b: = nan is outside the valid range"),
        (math.inf, r"a\.b: = inf is outside the valid range"),
        (True, r"a\.b: must be a number in \[0\.1, 1\.25\], got True"),
        ("1", r"a\.b: must be a number in \[0\.1, 1\.25\], got '1'"),
    ],
)
def test_number_outside_the_range_or_not_a_number_is_named(value, message):
    with pytest.raises(ScenarioError, match=message):
        F.number(value, "a.b", 0.1, 1.25)


def test_integer_seed_string_boolean_and_choice_refuse_with_the_valid_values():
    for value in (1, 501, 3.0, True):
        with pytest.raises(
            ScenarioError, match=rf"s\.toml: n: must be an integer in \[2, 500\], got {value!r}"
        ):
            F.integer(value, "n", 2, 500)
    for value in (-1, 1.5, False):
        with pytest.raises(ScenarioError, match=rf"seed: must be a non-negative integer, got {value!r}"):
            F.seed(value, "seed")
    with pytest.raises(ScenarioError, match=r"m: 'lsq' is not one of ols, wls, fgls"):
        F.choice("lsq", "m", ("ols", "wls", "fgls"))
    with pytest.raises(ScenarioError, match=r"noise: must be true or false, got 'yes'"):
        F.boolean("yes", "noise")
    with pytest.raises(ScenarioError, match=r"name: must be a non-empty string"):
        F.string("", "name", allow_empty=False)
    assert F.string("", "name") == ""


def test_vector_names_its_length_and_the_offending_element():
    with pytest.raises(ScenarioError, match=r"v: must be a list of 3 numbers, got \[1, 2\]"):
        F.vector([1, 2], "v", 3, 0.0, 5.0)
    with pytest.raises(ScenarioError, match=r"v\[2\]: = 6 is outside the valid range \[0, 5\]"):
        F.vector([1, 2, 6], "v", 3, 0.0, 5.0)


def test_table_names_the_first_unknown_key_with_its_dotted_path():
    assert F.table({"a": 1}, "t", ("a", "b")) == {"a": 1}
    with pytest.raises(ScenarioError, match=r"s\.toml: t\.c: unknown key; valid keys: a, b$"):
        F.table({"c": 1, "d": 2, "a": 0}, "t", ("a", "b"))
    with pytest.raises(ScenarioError, match=r"^s\.toml: colour: unknown key"):  # top level: no dot
        F.table({"colour": 1}, "", ("name",))
    with pytest.raises(ScenarioError, match=r"t: must be a table, got list \[1\]"):
        F.table([1], "t")
    assert str(Fields().error("x", "bad")) == "x: bad"  # no source: no file prefix
