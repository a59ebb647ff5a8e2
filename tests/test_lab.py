"""The lab's geometry and rules against closed forms: the tension rule's boundaries, the force
sensor's measuring range per axis, hook and ring positions, and a scenario's [lab] overrides."""

import numpy as np
import pytest

from vtestbed.errors import OutOfRangeError, ScenarioError, SensorOverloadError, UnknownNameError
from vtestbed.lab import (
    DEFAULT_SCANNER_DISTANCE_M,
    DEFAULT_TENSION_N,
    PAPER_LAB,
    BlockSpec,
    ForceSensorSpec,
    LabSetup,
    parse_lab,
)
from vtestbed.schema import Fields

# Paper Table 4 (ATI SI-330-30): |Fx|, |Fy| <= 330 N, |Fz| <= 990 N, |Tx|, |Ty|, |Tz| <= 30 N*m.
PAPER_RANGE = (330.0, 330.0, 990.0, 30.0, 30.0, 30.0)
AXES = ("Fx", "Fy", "Fz", "Tx", "Ty", "Tz")


def test_paper_defaults():
    assert PAPER_LAB.sensor.wrench_range == PAPER_RANGE
    assert DEFAULT_TENSION_N == 200.0  # the paper's wire load
    assert PAPER_LAB.scanner.working_distance_m[0] <= DEFAULT_SCANNER_DISTANCE_M
    assert DEFAULT_SCANNER_DISTANCE_M <= PAPER_LAB.scanner.working_distance_m[1]
    assert PAPER_LAB.tension_range_N == (1.0, 990.0)


@pytest.mark.parametrize("tension", [1.0, 1, 200.0, 989.999, 990.0, np.float64(500.0), np.int64(7)])
def test_tension_inside_the_rule_is_returned_as_a_float(lab, tension):
    value = lab.check_tension(tension)
    assert isinstance(value, float) and value == float(tension)


@pytest.mark.parametrize("tension", [0.999, 0.0, -5.0, 990.001, 1e4, float("nan"), float("inf")])
def test_tension_outside_1_to_990_N_is_refused_naming_the_field_and_range(lab, tension):
    with pytest.raises(
        OutOfRangeError, match=r"load\.tension_N = .* N is outside the valid range \[1, 990\] N"
    ):
        lab.check_tension(tension, "load.tension_N")


@pytest.mark.parametrize("tension", [True, "200", None, [200.0]])
def test_tension_that_is_not_a_number_is_refused(lab, tension):
    with pytest.raises(OutOfRangeError, match=r"tension_N must be a number in \[1, 990\] N"):
        lab.check_tension(tension)


def test_tension_ceiling_follows_the_sensors_largest_force_range():
    sensor = ForceSensorSpec(wrench_range=(100.0, 450.0, 300.0, 10.0, 10.0, 10.0))
    lab = LabSetup(sensor=sensor)
    assert lab.tension_range_N == (1.0, 450.0)  # max(|Fx|, |Fy|, |Fz|), not a torque limit
    assert lab.check_tension(450.0) == 450.0
    with pytest.raises(OutOfRangeError, match=r"\[1, 450\] N"):
        lab.check_tension(450.5)


@pytest.mark.parametrize("axis", range(6))
def test_sensor_range_boundary_per_axis(axis):
    spec = ForceSensorSpec()
    limit = PAPER_RANGE[axis]
    for sign in (1.0, -1.0):
        wrench = np.zeros(6)
        wrench[axis] = sign * limit  # on the boundary: accepted
        np.testing.assert_array_equal(spec.check(wrench), wrench)
        wrench[axis] = sign * limit * (1 + 1e-9)
        unit = "N" if axis < 3 else r"N\*m"
        with pytest.raises(
            SensorOverloadError,
            match=rf"reading: {AXES[axis]} = .* {unit} is outside the measuring range \[-{limit:g}, {limit:g}\] {unit}",
        ):
            spec.check(wrench, "reading")


def test_sensor_refuses_non_finite_or_misshapen_wrenches():
    spec = ForceSensorSpec()
    for bad in ([0, 0, np.nan, 0, 0, 0], [0, 0, 0, np.inf, 0, 0], [0.0] * 5):
        with pytest.raises(SensorOverloadError, match=r"w must be 6 finite numbers \(Fx\.\.Tz\)"):
            spec.check(bad, "w")


def test_hooks_sit_at_the_hidden_face_centres_for_any_edge():
    for edge in (0.08, 0.05, 0.13):
        block = BlockSpec(edge=edge)
        # B's origin is the scanned corner; the block is [-edge, 0]^3
        np.testing.assert_allclose(block.hook("hook_x"), [-edge, -edge / 2, -edge / 2], rtol=0, atol=1e-15)
        np.testing.assert_allclose(block.hook("hook_y"), [-edge / 2, -edge, -edge / 2], rtol=0, atol=1e-15)
        np.testing.assert_allclose(block.hook("hook_edge"), [-edge, -edge, -edge / 2], rtol=0, atol=1e-15)
        assert block.mass == pytest.approx(2700.0 * edge**3, rel=1e-14)
    with pytest.raises(UnknownNameError, match="unknown hook 'eye'; valid names: hook_edge, hook_x, hook_y"):
        BlockSpec().hook("eye")


def test_rings_are_row_major_on_the_table_top(lab):
    xs, ys = (1.1, 1.6, 2.1), (-0.7, 0.0, 0.7)
    for k in range(9):
        np.testing.assert_array_equal(lab.table.anchor(f"ring_{k + 1}"), [xs[k // 3], ys[k % 3], 0.5])
    with pytest.raises(UnknownNameError, match="unknown anchor 'ring_10'; valid names: ring_1, ring_2"):
        lab.table.anchor("ring_10")


def test_block_and_sensor_frames_in_the_flange(lab):
    # sensor origin: adapter (10 mm) + sensor height (33.3 mm) on the flange z axis; block corner:
    # a further 20 mm stem and the 80 mm edge, at (e/2, e/2) so the cube is centred on the axis
    np.testing.assert_allclose(lab.sensor_in_flange[:3, 3], [0, 0, 0.0433], rtol=0, atol=1e-15)
    np.testing.assert_allclose(lab.block_in_flange[:3, 3], [0.04, 0.04, 0.1433], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(lab.block_in_flange[:3, :3], np.eye(3))


def test_lab_overrides_move_rings_block_and_ranges_to_the_closed_form():
    table = {
        "table": {"height_m": 0.8, "ring_x_m": [1.0, 2.0], "ring_y_m": [-0.5, 0.25, 0.5, 0.75]},
        "block": {"edge_m": 0.1, "standoff_m": 0.03, "density_kg_m3": 7850.0},
        "force_sensor": {"range_N_Nm": [300, 300, 600, 20, 20, 25]},
        "wire": {"axial_rigidity_N": 1e6},
    }
    lab = parse_lab(table, Fields("lab.toml"))
    anchors = lab.table.anchors
    assert len(anchors) == 8
    for k in range(8):  # row-major: x outer, y inner
        np.testing.assert_array_equal(
            anchors[f"ring_{k + 1}"], [(1.0, 2.0)[k // 4], (-0.5, 0.25, 0.5, 0.75)[k % 4], 0.8]
        )
    np.testing.assert_allclose(lab.block_in_flange[:3, 3], [0.05, 0.05, 0.0433 + 0.03 + 0.1], atol=1e-15)
    assert lab.block.mass == pytest.approx(7850.0 * 0.1**3, rel=1e-14)
    np.testing.assert_allclose(lab.block.hook("hook_edge"), [-0.1, -0.1, -0.05], atol=1e-15)
    assert lab.tension_range_N == (1.0, 600.0) and lab.wire.axial_rigidity == 1e6
    # untouched parts keep the paper's values
    assert lab.table.center == PAPER_LAB.table.center and lab.scanner == PAPER_LAB.scanner
    assert parse_lab({}, Fields()) == PAPER_LAB


@pytest.mark.parametrize(
    "table, message",
    [
        ({"table": {"height_m": 5.0}}, r"lab\.toml: lab\.table\.height_m: = 5 is outside the valid range \[0, 3\]"),
        ({"table": {"height_m": "high"}}, r"lab\.table\.height_m: must be a number in \[0, 3\], got 'high'"),
        ({"table": {"colour": 1}}, r"lab\.table\.colour: unknown key; valid keys: center_m, size_m, height_m"),
        ({"bench": {}}, r"lab\.bench: unknown key; valid keys: table, block, force_sensor, wire"),
        ({"table": {"ring_x_m": []}}, r"lab\.table\.ring_x_m: must be a non-empty list of numbers in \[-10, 10\]"),
        ({"table": {"ring_y_m": [0.0, 11.0]}}, r"lab\.table\.ring_y_m\[1\]: = 11 is outside the valid range \[-10, 10\]"),
        ({"table": {"center_m": [1.0]}}, r"lab\.table\.center_m: must be a list of 2 numbers"),
        ({"block": {"edge_m": 0.01}}, r"lab\.block\.edge_m: = 0\.01 is outside the valid range \[0\.02, 0\.3\]"),
        ({"force_sensor": {"range_N_Nm": [1, 2, 3, 4, 5]}}, r"lab\.force_sensor\.range_N_Nm: must be a list of 6 numbers"),
        ({"wire": {"axial_rigidity_N": 10.0}}, r"lab\.wire\.axial_rigidity_N: = 10 is outside the valid range \[1000, 1e\+09\]"),
        ({"table": 3}, r"lab\.table: must be a table, got int 3"),
    ],
)  # fmt: skip
def test_malformed_lab_names_the_field_and_the_valid_range(table, message):
    with pytest.raises(ScenarioError, match=message):
        parse_lab(table, Fields("lab.toml"))
