"""The lab's geometry and rules against closed forms: the tension rule's boundaries and the limit
that sets them, the force sensor's measuring range per axis, hook and ring positions, a scenario's
[lab] overrides, and the lab derived from a robot's reach (closed-form reach, exact paper lab for
the KR60) with the checks that refuse a lab the robot cannot use."""

import numpy as np
import pytest

from vtestbed.errors import OutOfRangeError, ScenarioError, SensorOverloadError, UnknownNameError
from vtestbed.lab import (
    DEFAULT_SCANNER_DISTANCE_M,
    DEFAULT_TENSION_N,
    PAPER_LAB,
    PAPER_RATED_PAYLOAD_KG,
    PAPER_REACH_M,
    BlockSpec,
    BlockZone,
    ForceSensorSpec,
    LabSetup,
    WireSpec,
    parse_lab,
)
from vtestbed.robot_lab import check_lab, lab_for_robot, robot_reach
from vtestbed.robots import load_robot
from vtestbed.schema import Fields

# Paper Table 4 (ATI SI-330-30): |Fx|, |Fy| <= 330 N, |Fz| <= 990 N, |Tx|, |Ty|, |Tz| <= 30 N*m.
PAPER_RANGE = (330.0, 330.0, 990.0, 30.0, 30.0, 30.0)
AXES = ("Fx", "Fy", "Fz", "Tx", "Ty", "Tz")


def test_paper_defaults():
    assert PAPER_LAB.sensor.wrench_range == PAPER_RANGE
    assert DEFAULT_TENSION_N == 200.0  # the paper's wire load
    assert PAPER_LAB.scanner.working_distance_m[0] <= DEFAULT_SCANNER_DISTANCE_M
    assert DEFAULT_SCANNER_DISTANCE_M <= PAPER_LAB.scanner.working_distance_m[1]
    # the KR60-3's rated payload, 60 kg * 9.81 m/s^2, is the lowest of the three limits
    assert PAPER_LAB.tension_range_N == (1.0, 588.6)
    assert PAPER_LAB.max_tension[1] == "the robot's rated payload (60 kg * 9.81 m/s^2)"
    assert PAPER_LAB.default_tension_N == DEFAULT_TENSION_N  # 200 N <= 588.6 N / 2: the paper's


def test_the_three_tension_limits_and_which_sets_it():
    swl = 1.77e9 * np.pi * 0.001**2 / 5  # 2 mm solid wire, 1770 MPa, safety factor 5: 1112.1 N
    assert PAPER_LAB.tension_limits_N == pytest.approx(
        {"the robot's rated payload (60 kg * 9.81 m/s^2)": 588.6, "the wire's safe working load": swl,
         "the ATI Delta SI-330-30's force range": 990.0}, rel=1e-12)  # fmt: skip
    thin = LabSetup(wire=WireSpec(breaking_load_N=2000.0))  # SWL 400 N, below the payload's 588.6 N
    assert thin.max_tension == (400.0, "the wire's safe working load")
    with pytest.raises(
        OutOfRangeError, match=r"t = 400\.5 N .* \[1, 400\] N \(taut, and at most 400 N, set by the wire's"
    ):
        thin.check_tension(400.5, "t")
    unknown = LabSetup(rated_payload_kg=None)  # a robot without a rated payload: the sensor binds
    assert unknown.max_tension == (990.0, "the ATI Delta SI-330-30's force range")
    capped = LabSetup(tension_cap_N=150.0)
    assert capped.max_tension == (150.0, "the lab's max_tension_N") and capped.default_tension_N == 75.0


@pytest.mark.parametrize("tension", [1.0, 1, 200.0, 588.599, 588.6, np.float64(500.0), np.int64(7)])
def test_tension_inside_the_rule_is_returned_as_a_float(lab, tension):
    value = lab.check_tension(tension)
    assert isinstance(value, float) and value == float(tension)


@pytest.mark.parametrize("tension", [0.999, 0.0, -5.0, 588.601, 990.0, 1e4, float("nan"), float("inf")])
def test_tension_outside_1_to_588_6_N_is_refused_naming_the_field_range_and_limit(lab, tension):
    with pytest.raises(
        OutOfRangeError,
        match=r"load\.tension_N = .* N is outside the valid range \[1, 588\.6\] N \(taut, and at most 588\.6 N, "
        r"set by the robot's rated payload \(60 kg \* 9\.81 m/s\^2\)\)$",
    ):
        lab.check_tension(tension, "load.tension_N")


@pytest.mark.parametrize("tension", [True, "200", None, [200.0]])
def test_tension_that_is_not_a_number_is_refused(lab, tension):
    with pytest.raises(OutOfRangeError, match=r"tension_N must be a number in \[1, 588\.6\] N"):
        lab.check_tension(tension)


def test_tension_ceiling_follows_the_sensors_largest_force_range():
    sensor = ForceSensorSpec(wrench_range=(100.0, 450.0, 300.0, 10.0, 10.0, 10.0))
    lab = LabSetup(sensor=sensor)
    assert lab.tension_range_N == (1.0, 450.0)  # max(|Fx|, |Fy|, |Fz|), not a torque limit
    assert lab.max_tension[1] == "the ATI Delta SI-330-30's force range"
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
        "wire": {"axial_rigidity_N": 1e6, "breaking_load_N": 2500.0},
        "zone": {"min_height_m": 0.9, "box_m": [0, -1, 0, 2, 1, 2]},
        "max_tension_N": 300.0,
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
    assert lab.wire.axial_rigidity == 1e6 and lab.wire.safe_working_load_N == 500.0  # 2500 N / 5
    assert lab.zone == BlockZone(0.9, (0.0, -1.0, 0.0, 2.0, 1.0, 2.0))
    assert lab.tension_range_N == (1.0, 300.0) and lab.max_tension[1] == "the lab's max_tension_N"
    # untouched parts keep the paper's values
    assert lab.table.center == PAPER_LAB.table.center and lab.scanner == PAPER_LAB.scanner
    assert parse_lab({}, Fields()) == PAPER_LAB


@pytest.mark.parametrize(
    "table, message",
    [
        ({"table": {"height_m": 5.0}}, r"lab\.toml: lab\.table\.height_m: = 5 is outside the valid range \[0, 3\]"),
        ({"table": {"height_m": "high"}}, r"lab\.table\.height_m: must be a number in \[0, 3\], got 'high'"),
        ({"table": {"colour": 1}}, r"lab\.table\.colour: unknown key; valid keys: center_m, size_m, height_m"),
        ({"bench": {}}, r"lab\.bench: unknown key; valid keys: table, block, force_sensor, wire, zone, max_tension_N"),
        ({"max_tension_N": 600.0}, r"lab\.max_tension_N: = 600 is outside the valid range \[1, 588\.6\]"),
        ({"max_tension_N": 0.5}, r"lab\.max_tension_N: = 0\.5 is outside the valid range \[1, 588\.6\]"),
        # a weaker wire lowers the ceiling the cap may reach: SWL = 1000 N / 5
        ({"wire": {"breaking_load_N": 1000.0}, "max_tension_N": 250.0}, r"lab\.max_tension_N: = 250 is outside the valid range \[1, 200\]"),
        ({"zone": {"box_m": [0, 0, 0, 1, 1]}}, r"lab\.zone\.box_m: must be a list of 6 numbers"),
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


# Closed-form reaches (largest flange distance from joint 2's axis, the arm stretched): KR60
# a2 + |(a3, d4)| + d6; UR10 (joints 2-4 parallel, d4 along the axis) a2 + a3 + |(d5, d6)|.
KR60_REACH = 0.85 + np.hypot(0.145, 0.82) + 0.17
UR10_REACH = 0.612 + 0.5723 + np.hypot(0.1157, 0.0922)


@pytest.mark.parametrize("name, closed_form", [("kuka_kr60_3", KR60_REACH), ("ur10", UR10_REACH)])
def test_reach_is_the_closed_form_and_bounds_random_poses(name, closed_form):
    robot = load_robot(name)
    assert robot_reach(robot) == pytest.approx(closed_form, rel=0, abs=1e-9)
    # a second computation: the flange's distance from joint 2's axis line in the base frame
    rng = np.random.default_rng(5)
    worst = 0.0
    for _ in range(2000):
        frames = robot.frame_poses(robot.random_pose(rng))
        axis, v = frames[1][:3, 2], frames[-1][:3, 3] - frames[1][:3, 3]
        worst = max(worst, np.linalg.norm(v - (v @ axis) * axis))
    assert closed_form * 0.97 < worst <= closed_form + 1e-12


def test_the_kr60s_lab_is_exactly_the_papers(robot):
    assert PAPER_REACH_M == pytest.approx(KR60_REACH, rel=0, abs=1e-15)
    assert robot.rated_payload_kg == PAPER_RATED_PAYLOAD_KG == 60.0  # robot.toml and the lab agree
    assert lab_for_robot(robot) == PAPER_LAB  # every field, bit for bit
    assert check_lab(PAPER_LAB, robot) is PAPER_LAB


def test_the_ur10s_lab_is_the_papers_scaled_about_its_shoulder():
    ur10 = load_robot("ur10")
    lab, s = lab_for_robot(ur10), UR10_REACH / KR60_REACH  # 0.7191
    shoulder_z = 0.1273  # d1: the UR10's joint 2 axis point is (0, 0, d1); the KR60's (0.35, 0, 0.815)
    np.testing.assert_allclose(lab.table.center, [s * (1.6 - 0.35), 0.0], atol=1e-8)
    np.testing.assert_allclose(lab.table.size, [1.4 * s, 1.8 * s], atol=1e-8)
    np.testing.assert_allclose(lab.table.ring_x, [s * (x - 0.35) for x in (1.1, 1.6, 2.1)], atol=1e-8)
    np.testing.assert_allclose(lab.table.ring_y, [-0.7 * s, 0.0, 0.7 * s], atol=1e-8)
    assert shoulder_z + s * (0.5 - 0.815) < 0 and lab.table.height == 0.0  # stops at the floor
    assert lab.zone.min_height == pytest.approx(shoulder_z + s * (0.8 - 0.815), abs=1e-8)
    assert lab.scanner_distance == pytest.approx(0.6 * s, abs=1e-8)  # 0.431 m, in 0.1-1.25 m
    assert lab.max_tension == (
        pytest.approx(98.1, abs=1e-12),
        "the robot's rated payload (10 kg * 9.81 m/s^2)",
    )
    assert lab.default_tension_N == pytest.approx(49.05, abs=1e-12)
    assert check_lab(lab, ur10) is lab


def test_a_lab_the_robot_cannot_use_is_refused_naming_the_field():
    ur10, kr60 = load_robot("ur10"), load_robot("kuka_kr60_3")
    # the paper's ring_4 (1.6, -0.7, 0.5) from the UR10's shoulder (0, 0, 0.1273): hypot(1.6, 0.7,
    # 0.3727) = 1.786 m; wire's reach = 1.332 m + hook_edge's |(-0.04, -0.04, 0.1033)| = 0.1178 m
    reach = f"{UR10_REACH + np.linalg.norm([-0.04, -0.04, 0.1033]):.3f}"
    with pytest.raises(ScenarioError, match=rf"lab\.table\.ring_x_m\[1\], ring_y_m\[0\]: ring_4 at \[1\.6, -0\.7, 0\.5\] m is "
                       rf"1\.786 m .* beyond the wire's reach; valid: at most {reach} m"):  # fmt: skip
        check_lab(PAPER_LAB, ur10, Fields("s.toml"))
    far = parse_lab(
        {"table": {"center_m": [3.5, 0.0], "size_m": [1.0, 1.0], "ring_x_m": [3.5], "ring_y_m": [0.0]}},
        Fields(),
    )
    # nearest table point (3.0, 0, 0.6433) from the KR60's shoulder circle (r 0.35, z 0.815): 2.656 m
    with pytest.raises(
        ScenarioError, match=r"lab\.table: out of reach: .* at least 2\.656 m .* reach 1\.853 m"
    ):
        check_lab(far, kr60)
    with pytest.raises(
        ScenarioError,
        match=r"lab\.table\.ring_y_m\[2\]: = 0\.95 is off the table top; valid range \[-0\.9, 0\.9\]",
    ):
        parse_lab({"table": {"ring_y_m": [0.0, 0.5, 0.95]}}, Fields(), kr60)
    with pytest.raises(ScenarioError, match=r"lab\.zone\.box_m: z_min = 2 must be below z_max = 1"):
        parse_lab({"zone": {"box_m": [0, -1, 2, 2, 1, 1]}}, Fields(), kr60)
    # the UR10 with rings moved within its reach is accepted
    near = {"table": {"center_m": [0.9, 0.0], "ring_x_m": [0.6, 0.9], "ring_y_m": [-0.3, 0.3]}}
    assert len(parse_lab(near, Fields(), ur10).table.anchors) == 4


def test_a_block_deeper_than_the_measuring_volume_has_no_stand_off():
    """The block's corners reach edge * sqrt(3) / 2 in front of and behind its centre seen along
    (1, 1, 1); the measuring volume is 0.3 m deep, so an edge above 0.3 / sqrt(3) = 0.1732 m fits at no
    stand-off, and the message states that edge (rounded down to a millimetre)."""
    from dataclasses import replace

    def lab(edge):
        return replace(PAPER_LAB, block=replace(PAPER_LAB.block, edge=edge))

    assert lab(0.173).scanner_distance_range_m() == (0.25, 1.1)  # 0.1 + 0.1498, 1.25 - 0.1498
    assert lab(0.174).scanner_distance_range_m() is None
    with pytest.raises(
        OutOfRangeError, match=r"no distance_m can scan a block of edge 0.2 m: .* at most 0.173 m$"
    ):
        lab(0.2).check_scanner_distance(0.6)
    assert lab(0.173).check_scanner_distance(0.25) == 0.25
    with pytest.raises(OutOfRangeError, match=r"distance_m must be a number in \[0.17, 1.18\] m, got 'far'"):
        PAPER_LAB.check_scanner_distance("far")


def test_the_largest_load_scale_is_where_the_first_axis_reaches_its_range():
    sensor = ForceSensorSpec()  # 330, 330, 990 N, 30 N*m
    base, per_newton = [0.0, 5.0, 10.0, 0.0, 0.0, 1.0], [1.0, 0.0, -1.0, 0.0, 0.0, 0.1]
    # Fx reaches 330 at 330 N, Fz -990 at 1000 N, Tz 30 at (30 - 1) / 0.1 = 290 N: Tz binds
    assert sensor.largest_load_scale(base, per_newton) == pytest.approx(290.0, abs=1e-9)
    top = sensor.largest_load_scale(base, per_newton)
    sensor.check(np.add(base, np.multiply(top - 1e-6, per_newton)))
    with pytest.raises(SensorOverloadError, match="Tz"):
        sensor.check(np.add(base, np.multiply(top + 1e-6, per_newton)))
    assert sensor.largest_load_scale([0, 0, 0, 31.0, 0, 0], per_newton) == 0.0  # out of range without load
    assert sensor.largest_load_scale(base, np.zeros(6)) == np.inf
