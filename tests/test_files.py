"""Reading TOML and JSON with errors that name the file, and atomic writes."""

import json
import math
import re

import pytest

from vtestbed.errors import DatasetError, ScenarioError
from vtestbed.files import read_json, read_toml, write_atomic, write_json_atomic, write_text_atomic


def test_toml_and_json_values_are_read_as_written(tmp_path):
    (tmp_path / "a.toml").write_text('name = "x"\nk = [2.1977e9, 0.1]\n[t]\nn = 3\n', encoding="utf-8")
    assert read_toml(tmp_path / "a.toml", "scenario file", ScenarioError) == {
        "name": "x",
        "k": [2.1977e9, 0.1],
        "t": {"n": 3},
    }
    (tmp_path / "a.json").write_text('{"k": [0.1, 1e-300], "s": "\\u00e9"}', encoding="utf-8")
    assert read_json(tmp_path / "a.json", "truth file", DatasetError) == {"k": [0.1, 1e-300], "s": "é"}
    (tmp_path / "l.json").write_text("[1, 2.5]")
    assert read_json(tmp_path / "l.json", "list file", DatasetError, kind=list) == [1, 2.5]


@pytest.mark.parametrize(
    "reader, error", [(read_toml, ScenarioError), (read_json, DatasetError)], ids=["toml", "json"]
)
def test_missing_file_or_a_folder_is_named(tmp_path, reader, error):
    with pytest.raises(
        error, match=rf"the file {re.escape(str(tmp_path / 'nope.x'))} is missing \(the file does not exist\)"
    ):
        reader(tmp_path / "nope.x", "the file", error)
    with pytest.raises(error, match=rf"setup {re.escape(str(tmp_path))} is not a file"):
        reader(tmp_path, "setup", error)


@pytest.mark.parametrize("reader", [read_toml, read_json], ids=["toml", "json"])
def test_text_that_is_not_utf8_names_the_file_and_the_byte(tmp_path, reader):
    path = tmp_path / "latin1.txt"
    path.write_bytes(b'{"name": "caf\xe9"}')  # Latin-1 e-acute: byte 13 (0-based) is not UTF-8
    with pytest.raises(
        ScenarioError,
        match=rf"{re.escape(str(path))}: not UTF-8 text \(byte 13\): is this the right scenario file\?",
    ):
        reader(path, "scenario file", ScenarioError)


def test_unparsable_text_names_the_file_and_the_format(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("name = [unclosed\n")
    with pytest.raises(ScenarioError, match=rf"{re.escape(str(bad))}: not valid TOML: .*at line 1, column 9"):
        read_toml(bad, "scenario file", ScenarioError)
    bad = tmp_path / "bad.json"
    bad.write_text('{"a": 1,}')
    with pytest.raises(DatasetError, match=rf"{re.escape(str(bad))}: not valid JSON: .*line 1 column 9"):
        read_json(bad, "truth file", DatasetError)


def test_json_of_the_wrong_kind_is_named(tmp_path):
    path = tmp_path / "list.json"
    path.write_text("[1, 2]")
    with pytest.raises(
        DatasetError, match=rf"{re.escape(str(path))}: the truth file must hold a JSON dict, got list"
    ):
        read_json(path, "truth file", DatasetError)
    path.write_text('"text"')
    with pytest.raises(DatasetError, match="must hold a JSON list, got str"):
        read_json(path, "plan", DatasetError, kind=list)


def test_atomic_writes_leave_the_new_file_and_no_temporary(tmp_path):
    data = {"k": [2.1977e9, 0.1, 1 / 3, math.pi], "name": "x"}
    path = write_json_atomic(tmp_path / "out.json", data)
    assert json.loads(path.read_text()) == data  # floats survive bit-exact (repr round trip)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]
    write_text_atomic(path, "replaced")
    assert path.read_text() == "replaced" and sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]


def test_a_failed_atomic_write_keeps_the_old_file_and_no_temporary(tmp_path):
    path = tmp_path / "out.txt"
    path.write_text("old")
    seen = []

    def half_then_fail(tmp):
        seen.append(tmp)
        tmp.write_text("half")
        raise RuntimeError("killed")

    with pytest.raises(RuntimeError, match="killed"):
        write_atomic(path, half_then_fail)
    assert path.read_text() == "old"
    assert seen[0].parent == tmp_path and seen[0] != path  # it wrote beside the target, not onto it
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.txt"]
