"""The dataset files: a bit-exact round trip of setup.json and tests.csv, the columns as the
format documents them, and malformed files refused naming the file, the line and the field."""

import csv
import dataclasses
import json
import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vtestbed.dataset import COLUMNS, DatasetSetup, read_setup, read_tests, write_setup
from vtestbed.dataset import TestRecord as Record  # under their own names pytest would try to
from vtestbed.dataset import TestWriter as Writer  # collect them as test classes
from vtestbed.errors import DatasetError

AXES = ("Fx", "Fy", "Fz", "Tx", "Ty", "Tz")


def test_columns_are_the_documented_ones():
    assert COLUMNS[:8] == ["test_id", "group", "q1_deg", "q2_deg", "q3_deg", "q4_deg", "q5_deg", "q6_deg"]
    units = ["N"] * 3 + ["Nm"] * 3
    assert COLUMNS[8:14] == [f"unloaded_{a}_{u}" for a, u in zip(AXES, units)]
    assert COLUMNS[14:20] == [f"loaded_{a}_{u}" for a, u in zip(AXES, units)]
    assert COLUMNS[20:] == [f"scanner_{c}" for c in ("x_m", "y_m", "z_m", "rx_rad", "ry_rad", "rz_rad")] + [
        "cloud_unloaded",
        "cloud_loaded",
    ]


def _setup(lab) -> DatasetSetup:
    block = lab.block_in_flange.copy()
    block[:3, :3] = Rotation.from_rotvec([0.1, -0.2, 0.3]).as_matrix()  # not the identity: rotations survive
    return DatasetSetup("kuka_kr60_3", "controller", block, lab.sensor_in_flange, 0.08, "my sensor",
                        (300.0, 300.0, 900.0, 25.0, 25.0, 25.0), "notes é")  # fmt: skip


def _records(root, count=4, seed=0):
    rng = np.random.default_rng(seed)
    (root / "clouds").mkdir(parents=True, exist_ok=True)
    out = []
    for i in range(count):
        pose = np.eye(4)
        pose[:3, :3] = Rotation.from_rotvec(rng.normal(0, 1, 3)).as_matrix()
        pose[:3, 3] = rng.normal(0, 1, 3)
        clouds = (root / "clouds" / f"T{i}_u.ply", root / "clouds" / f"T{i}_l.ply")
        for c in clouds:
            c.write_bytes(b"")
        group = "validation" if i == count - 1 else "identification"
        out.append(Record(f"T{i:03d}", group, rng.uniform(-180, 180, 6), rng.normal(0, 100, 6),
                          rng.normal(0, 100, 6) / 7, pose, *clouds))  # fmt: skip
    return out


def _write(root, records):
    with Writer(root) as writer:
        for r in records:
            writer.append(r)


def test_setup_round_trip_is_exact(tmp_path, lab):
    setup = _setup(lab)
    write_setup(tmp_path, setup)
    back = read_setup(tmp_path)
    assert np.array_equal(back.block_in_flange, setup.block_in_flange)
    assert np.array_equal(back.sensor_in_flange, setup.sensor_in_flange)
    assert (back.robot, back.angle_convention, back.block_edge) == ("kuka_kr60_3", "controller", 0.08)
    assert back.sensor_range == setup.sensor_range and back.notes == "notes é"
    assert back.sensor_spec.name == "my sensor" and back.sensor_spec.max_force == 900.0
    assert json.loads((tmp_path / "setup.json").read_text())["format"] == "vtestbed-dataset/1"
    # no mount side recorded: none in the file, zero when read (a dataset from before 2026-12-02)
    assert "mount_side_mass_kg" not in json.loads((tmp_path / "setup.json").read_text())["force_sensor"]
    assert (back.sensor_mount_mass, back.sensor_mount_com) == (0.0, (0.0, 0.0, 0.0))
    mounted = dataclasses.replace(setup, sensor_mount_mass=0.45, sensor_mount_com=(0.001, -0.002, 0.0133))
    write_setup(tmp_path, mounted)
    back = read_setup(tmp_path)
    assert (back.sensor_mount_mass, back.sensor_mount_com) == (0.45, (0.001, -0.002, 0.0133))
    # the readings' noise: absent before 2026-12-02 (None: not known), exact when written
    assert back.sensor_noise_std is None
    noisy = dataclasses.replace(setup, sensor_noise_std=(0.0625, 0.0625, 0.0625, 0.0019, 0.0019, 0.0019))
    write_setup(tmp_path, noisy)
    assert read_setup(tmp_path).sensor_noise_std == noisy.sensor_noise_std


def test_tests_round_trip_is_bit_exact_and_appends(tmp_path):
    records = _records(tmp_path)
    _write(tmp_path, records[:2])
    _write(tmp_path, records[2:])  # a resumed run appends below the header
    back = read_tests(tmp_path)
    assert [r.test_id for r in back] == [r.test_id for r in records]
    assert [r.group for r in back] == ["identification"] * 3 + ["validation"]
    for r, b in zip(records, back):
        assert np.array_equal(b.q_deg, r.q_deg)
        assert np.array_equal(b.wrench_unloaded, r.wrench_unloaded)
        assert np.array_equal(b.wrench_loaded, r.wrench_loaded)
        assert np.array_equal(b.scanner_pose[:3, 3], r.scanner_pose[:3, 3])
        # the rotation is stored as a rotation vector: equal to rounding
        np.testing.assert_allclose(b.scanner_pose, r.scanner_pose, rtol=0, atol=1e-15)
        assert b.cloud_unloaded == r.cloud_unloaded.resolve() and b.cloud_loaded == r.cloud_loaded.resolve()
    rows = list(csv.reader((tmp_path / "tests.csv").open()))
    assert rows[0] == COLUMNS and len(rows) == 5  # one header
    assert rows[1][-2:] == ["clouds/T0_u.ply", "clouds/T0_l.ply"]  # paths relative to the dataset
    with Writer(tmp_path) as writer:  # a resumed run knows what is done
        assert writer.done == {r.test_id for r in records}


@pytest.fixture
def dataset(tmp_path, lab):
    write_setup(tmp_path, _setup(lab))
    _write(tmp_path, _records(tmp_path))
    return tmp_path


def _edit_setup(root, **changes):
    data = json.loads((root / "setup.json").read_text())
    for key, value in changes.items():
        if value is KeyError:
            del data[key]
        else:
            data[key] = value
    (root / "setup.json").write_text(json.dumps(data))


@pytest.mark.parametrize(
    "changes, message",
    [
        ({"robot": KeyError}, r"key 'robot' is missing"),
        ({"block_edge_m": KeyError}, r"key 'block_edge_m' is missing"),
        ({"angle_convention": "kuka"}, r"angle_convention must be 'dh' or 'controller', got 'kuka'"),
        ({"force_sensor": {"range_N_Nm": [1, 2, 3]}}, r"force_sensor\.range_N_Nm must be 6 numbers \(Fx\.\.Tz\)"),
        ({"block_in_flange": np.eye(3).tolist()}, r"block_in_flange must be a 4x4 rigid transform"),
        ({"sensor_in_flange": (2 * np.eye(4)).tolist()}, r"sensor_in_flange must be a 4x4 rigid transform"),
    ],
)  # fmt: skip
def test_malformed_setup_names_the_file_and_the_key(dataset, changes, message):
    _edit_setup(dataset, **changes)
    with pytest.raises(DatasetError, match=re.escape(str(dataset / "setup.json")) + ": " + message):
        read_setup(dataset)


def test_unreadable_setup_names_the_file(dataset):
    (dataset / "setup.json").write_text("{robot: kr60}")
    with pytest.raises(DatasetError, match=r"setup\.json: not valid JSON"):
        read_setup(dataset)
    (dataset / "setup.json").unlink()
    with pytest.raises(DatasetError, match=r"dataset setup file .*setup\.json is missing"):
        read_setup(dataset)


def _edit_tests(root, edit):
    with (root / "tests.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    fields = edit(rows) or COLUMNS
    with (root / "tests.csv").open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fields, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)


def test_malformed_tests_name_the_file_line_and_field(dataset):
    where = re.escape(str(dataset / "tests.csv"))
    _edit_tests(dataset, lambda rows: rows[2].update({"q3_deg": "ninety"}))
    with pytest.raises(
        DatasetError,
        match=rf"{where} line 4 \(test 'T002'\): q3_deg must be a number .*got 'ninety'",
    ):
        read_tests(dataset)
    _edit_tests(dataset, lambda rows: rows[2].update({"q3_deg": "nan"}))
    with pytest.raises(DatasetError, match=r"line 4 \(test 'T002'\): .* must be finite numbers"):
        read_tests(dataset)
    _edit_tests(dataset, lambda rows: rows[2].update({"q3_deg": "1.5", "group": "calibration"}))
    with pytest.raises(
        DatasetError, match=r"line 4 .*group must be one of identification, validation, got 'calibration'"
    ):
        read_tests(dataset)
    _edit_tests(dataset, lambda rows: rows[2].update({"group": "identification", "test_id": "T001"}))
    with pytest.raises(DatasetError, match=rf"{where}: duplicate test ids \['T001'\]"):
        read_tests(dataset)
    _edit_tests(dataset, lambda rows: [c for c in COLUMNS if c != "loaded_Ty_Nm"])
    with pytest.raises(DatasetError, match=rf"{where}: columns missing: loaded_Ty_Nm"):
        read_tests(dataset)
    (dataset / "tests.csv").unlink()
    with pytest.raises(DatasetError, match=rf"tests file {where} is missing"):
        read_tests(dataset)


def test_missing_clouds_and_overloads_are_named(dataset):
    (dataset / "clouds" / "T1_l.ply").unlink()
    with pytest.raises(
        DatasetError,
        match=r"line 3 \(test 'T001'\): point cloud .*T1_l\.ply is missing \(4 tests need 8 clouds, 7 found",
    ):
        read_tests(dataset)
    assert len(read_tests(dataset, check_files=False)) == 4
    _edit_tests(dataset, lambda rows: rows[0].update({"unloaded_Fz_N": "-901.5"}))
    with pytest.raises(
        DatasetError,
        match=r"line 2 \(test 'T000'\): unloaded wrench: Fz = -901\.50 N is outside the measuring range \[-900, 900\] N",
    ):
        read_tests(dataset, check_files=False, sensor_range=(300.0, 300.0, 900.0, 25.0, 25.0, 25.0))
    assert len(read_tests(dataset, check_files=False)) == 4  # without a range nothing is checked
