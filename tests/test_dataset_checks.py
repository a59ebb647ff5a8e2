"""Malformed dataset files found by fuzzing (issue 13): every type, shape and finiteness error is a
DatasetError naming the file, the field (or line) and the valid values; nothing passes as nonsense."""

import json
import re

import numpy as np
import pytest
from test_dataset import _edit_setup, _edit_tests, _records, _setup, _write

from vtestbed.comparison import read_truth
from vtestbed.dataset import read_setup, read_tests, write_setup
from vtestbed.dataset_repeats import read_repeats
from vtestbed.errors import DatasetError


@pytest.fixture
def dataset(tmp_path, lab):
    write_setup(tmp_path, _setup(lab))
    _write(tmp_path, _records(tmp_path))
    return tmp_path


NAN_T = np.eye(4).tolist()
NAN_T[0][3] = float("nan")
FAR_T = np.eye(4).tolist()
FAR_T[2][3] = 5.0
MIRROR = np.diag([1.0, 1.0, -1.0, 1.0]).tolist()


@pytest.mark.parametrize(
    "changes, message",
    [
        ({"force_sensor": "ati"}, r"force_sensor must be a table \{\"name\": \.\.\., \"range_N_Nm\": \[6 numbers\]\}, got 'ati'"),
        ({"force_sensor": {"range_N_Nm": [330, 330, 990, 30, 30, float("nan")]}}, r"force_sensor\.range_N_Nm must be 6 numbers \(Fx\.\.Tz\), each in \(0, 1e\+06\]"),
        ({"force_sensor": {"range_N_Nm": [330, 330, 990, 30, 30, 0]}}, r"force_sensor\.range_N_Nm must be 6 numbers .*got \[330, 330, 990, 30, 30, 0\]"),
        ({"force_sensor": {"range_N_Nm": [330, 330, 990, 30, 30, "30"]}}, r"force_sensor\.range_N_Nm must be 6 numbers .*'30'\]"),
        ({"force_sensor": {"name": 7, "range_N_Nm": [1] * 6}}, r"force_sensor\.name must be a string, got 7"),
        ({"block_edge_m": "big"}, r"block_edge_m must be a number in \[0\.001, 1\] m, got 'big'"),
        ({"block_edge_m": -0.08}, r"block_edge_m must be a number in \[0\.001, 1\] m, got -0\.08"),
        ({"block_edge_m": float("inf")}, r"block_edge_m must be a number in \[0\.001, 1\] m, got inf"),
        ({"block_edge_m": True}, r"block_edge_m must be a number"),
        ({"block_in_flange": [[1, 0, 0, 0], [0, 1, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}, r"block_in_flange must be a 4x4 rigid transform"),
        ({"block_in_flange": NAN_T}, r"block_in_flange must be a 4x4 rigid transform \(4 rows of 4 finite numbers"),
        ({"block_in_flange": FAR_T}, r"block_in_flange must be .*translation within 2 m of the flange"),
        ({"sensor_in_flange": MIRROR}, r"sensor_in_flange must be a 4x4 rigid transform"),
        ({"sensor_in_flange": "eye"}, r"sensor_in_flange must be a 4x4 rigid transform"),
        ({"robot": 5}, r"robot must be a non-empty string, got 5"),
        ({"robot": ""}, r"robot must be a non-empty string, got ''"),
        ({"angle_convention": ["dh"]}, r"angle_convention must be 'dh' or 'controller', got \['dh'\]"),
    ],
)  # fmt: skip
def test_setup_of_the_wrong_type_shape_or_range_is_refused(dataset, changes, message):
    _edit_setup(dataset, **changes)
    with pytest.raises(DatasetError, match=re.escape(str(dataset / "setup.json")) + ": " + message):
        read_setup(dataset)


def test_setup_that_is_a_number_or_not_utf8_is_refused(dataset):
    (dataset / "setup.json").write_text("5")
    with pytest.raises(
        DatasetError, match=r"setup\.json: the dataset setup file must hold a JSON dict, got int"
    ):
        read_setup(dataset)
    (dataset / "setup.json").write_bytes(b'{"robot": "kr\xe960"}')
    with pytest.raises(DatasetError, match=r"setup\.json: not UTF-8 text \(byte 13\)"):
        read_setup(dataset)


def _row_edit(index, **values):
    return lambda rows: rows[index].update(values)


@pytest.mark.parametrize(
    "edit, message",
    [
        (_row_edit(1, cloud_loaded="/etc/passwd"), r"line 3 \(test 'T001'\): cloud_loaded '/etc/passwd' must be a path inside the dataset folder .*e\.g\. clouds/T001_loaded\.ply"),
        (_row_edit(1, cloud_unloaded="../../x.ply"), r"line 3 \(test 'T001'\): cloud_unloaded '\.\./\.\./x\.ply' must be a path inside"),
        (_row_edit(1, cloud_unloaded="clouds/../../x.ply"), r"line 3 .*: cloud_unloaded 'clouds/\.\./\.\./x\.ply' must be a path inside"),
        (_row_edit(1, cloud_unloaded=""), r"line 3 .*: cloud_unloaded '' must be a path inside"),
        (_row_edit(0, loaded_Fx_N="1e400"), r"line 2 \(test 'T000'\): loaded_Fx_N = '1e400': .* must be finite numbers"),
        (_row_edit(0, scanner_rx_rad="inf"), r"line 2 .*scanner_rx_rad = 'inf'"),
        (_row_edit(3, test_id=" "), r"line 5 \(test ' '\): test_id must be a non-empty name"),
    ],
)  # fmt: skip
def test_tests_rows_with_bad_values_or_escaping_clouds_are_refused(dataset, edit, message):
    _edit_tests(dataset, edit)
    with pytest.raises(DatasetError, match=re.escape(str(dataset / "tests.csv")) + " " + message):
        read_tests(dataset, check_files=False)


def test_tests_rows_cut_short_or_too_long_and_bad_bytes_are_refused(dataset):
    path = dataset / "tests.csv"
    lines = path.read_text().splitlines()
    path.write_text("\n".join([*lines[:2], lines[2].rsplit(",", 1)[0], *lines[3:]]) + "\n")  # last field gone
    with pytest.raises(DatasetError, match=r"tests\.csv line 3: 27 fields, the header has 28"):
        read_tests(dataset, check_files=False)
    path.write_text("\n".join([*lines[:4], lines[4] + ",extra"]) + "\n")
    with pytest.raises(DatasetError, match=r"tests\.csv line 5: 29 fields, the header has 28"):
        read_tests(dataset, check_files=False)
    path.write_bytes("\n".join(lines).encode() + b"\n\xff\xfe,1\n")
    with pytest.raises(DatasetError, match=r"tests\.csv: not UTF-8 text \(byte \d+\)"):
        read_tests(dataset, check_files=False)
    path.write_text("\n".join(lines) + "\n\0\n")
    with pytest.raises(DatasetError, match=r"tests\.csv line 6: 1 fields, the header has 28"):
        read_tests(dataset, check_files=False)
    path.write_text("\n".join(lines) + "\n\n")  # a trailing blank line is harmless
    assert len(read_tests(dataset, check_files=False)) == 4


def test_a_spreadsheets_byte_order_mark_is_read_and_a_wrong_delimiter_is_shown(dataset):
    """Excel's "CSV UTF-8" starts with a byte order mark, which hid the first column (test_id);
    a semicolon-separated file is one column, and the error shows the header as the file has it."""
    path = dataset / "tests.csv"
    text = path.read_text()
    path.write_bytes(b"\xef\xbb\xbf" + text.replace("\n", "\r\n").encode())
    assert [r.test_id for r in read_tests(dataset, check_files=False)] == ["T000", "T001", "T002", "T003"]
    path.write_text(text.replace(",", ";"))
    with pytest.raises(DatasetError) as err:
        read_tests(dataset, check_files=False)
    assert re.fullmatch(
        r".*tests\.csv: columns missing: test_id, group, .*, cloud_loaded \(columns: test_id, .*, cloud_loaded; "
        r"comma-separated; the file's header has test_id;group;q1_deg;.{150,}\)",
        str(err.value),
    )
    path.write_text("")
    with pytest.raises(DatasetError, match=r"the file's header has nothing \(an empty file\)\)$"):
        read_tests(dataset, check_files=False)


def test_repeat_scans_outside_the_folder_are_refused(dataset):
    (dataset / "repeats.csv").write_text("test_id,repeat,cloud\nT000,1,/tmp/x.ply\n")
    with pytest.raises(
        DatasetError, match=r"repeats\.csv line 2 \(test 'T000'\): cloud '/tmp/x\.ply' must be a path inside"
    ):
        read_repeats(dataset, check_files=False)  # fmt: skip
    (dataset / "repeats.csv").write_text("test_id,repeat,cloud\nT000,1\n")
    with pytest.raises(DatasetError, match=r"repeats\.csv line 2: 2 fields, the header has 3"):
        read_repeats(dataset, check_files=False)


@pytest.mark.parametrize(
    "text, message",
    [
        ('{"stiffness_true_Nm_per_rad": [1, 2', r"truth\.json: not valid JSON"),
        ("3.5", r"truth\.json: the truth file must hold a JSON dict, got float"),
        ('{"stiffness_true_Nm_per_rad": "stiff"}', r"truth\.json: stiffness_true_Nm_per_rad must be numbers \(one per joint\), each in \[10, 1e\+09\] N\*m/rad, got 'stiff'"),
        ('{"stiffness_true_Nm_per_rad": [1e9, NaN]}', r"truth\.json: stiffness_true_Nm_per_rad must be 2 numbers \(one per joint\), each in \[10, 1e\+09\] N\*m/rad, got \[1000000000\.0, nan\]"),
        ('{"stiffness_true_Nm_per_rad": [1e9, true]}', r"stiffness_true_Nm_per_rad must be 2 numbers \(one per joint\), each in \[10, 1e\+09\]"),
        ('{"stiffness_true_Nm_per_rad": [1e9], "tests": [1]}', r"truth\.json: tests must be a table of the simulated tests by id, got \[1\]"),
    ],
)  # fmt: skip
def test_corrupt_or_wrong_shaped_truth_is_refused(tmp_path, text, message):
    (tmp_path / "truth.json").write_text(text)
    with pytest.raises(DatasetError, match=re.escape(str(tmp_path)) + ".*" + message):
        read_truth(tmp_path)
    (tmp_path / "truth.json").write_text(json.dumps({"stiffness_true_Nm_per_rad": [2.5e6, 1e6]}))
    assert read_truth(tmp_path)["stiffness_true_Nm_per_rad"] == [2.5e6, 1e6]
