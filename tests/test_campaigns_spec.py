"""Campaign schema, cells, seeds and noise scaling."""

import copy

import numpy as np
import pytest
from quick_campaign import BASE, ROOT, campaign_data

from vtestbed.campaigns.spec import AXES, POSE_SETS, load_campaign, parse_campaign, scaled_noise
from vtestbed.errors import ScenarioError
from vtestbed.world.scan_noise import ScanNoise


@pytest.mark.parametrize(
    "table, field, words",
    [
        ({"axes": {"noise": [1.0]}}, "campaign.axes.noise", ["unknown axis", *AXES]),
        ({"axes": {"n_tests": []}}, "campaign.axes.n_tests", ["empty"]),
        ({"axes": {"n_tests": [3, 1]}}, "campaign.axes.n_tests[1]", ["[2, 500]", "1"]),
        ({"axes": {"n_tests": [3, 3.5]}}, "campaign.axes.n_tests[1]", ["integer"]),
        ({"axes": {"n_tests": [21]}}, "campaign.axes.n_tests", ["21 tests exceed", "20"]),
        ({"axes": {"n_tests": [4, 4]}}, "campaign.axes.n_tests", ["twice"]),
        ({"axes": {"pose_set": ["kappa"]}}, "campaign.axes.pose_set[0]", list(POSE_SETS)),
        ({"axes": {"method": ["wls"]}}, "campaign.axes.method[0]", ["ols", "fgls"]),
        (
            {"axes": {"scanner_noise_scale": [1.0, -0.5]}},
            "campaign.axes.scanner_noise_scale[1]",
            ["[0, 1000]"],
        ),
        (
            {"axes": {"scanner_noise_scale": [200.0]}},
            "campaign.axes.scanner_noise_scale[0]",
            ["out of range"],
        ),
        ({"axes": {"ft_noise_scale": "1"}}, "campaign.axes.ft_noise_scale", ["list"]),
        ({"axes": {}}, "campaign.axes", ["non-empty", "pose_set"]),
        ({"trials": 0}, "campaign.trials", ["[1, 100000]"]),
        ({"seed": -1}, "campaign.seed", ["non-negative"]),
        ({"paired": "yes"}, "campaign.paired", ["true or false"]),
        ({"trails": 3}, "campaign.trails", ["unknown key", "trials"]),
        ({"pose_sets": {"pool": 2}}, "campaign.pose_sets.pool", ["[5, 2000]"]),
        ({"pose_sets": {"criterion": "G"}}, "campaign.pose_sets.criterion", ["D, A, E"]),
        ({"pose_sets": {"box_m": [0, 0, 0, 1, 1]}}, "campaign.pose_sets.box_m", ["6 numbers"]),
        ({"pose_sets": {"colour": 1}}, "campaign.pose_sets.colour", ["unknown key", "pool"]),
    ],
)
def test_invalid_campaign_names_the_field(table, field, words):
    with pytest.raises(ScenarioError) as info:
        parse_campaign(campaign_data(**table), "c.toml")
    message = str(info.value)
    assert message.startswith(f"c.toml: {field}:"), message
    for word in words:
        assert word in message, message


def test_axis_that_cannot_change_anything_is_refused():
    data = campaign_data(axes={"scanner_noise_scale": [1.0, 2.0]})
    data["scanner"]["noise"] = False
    with pytest.raises(
        ScenarioError, match="scanner_noise_scale: the base scenario has scanner.noise = false"
    ):
        parse_campaign(data)
    data = campaign_data(axes={"ft_noise_scale": [1.0, 2.0]})
    data["force_sensor"]["noise_std"] = [0.0] * 6
    with pytest.raises(
        ScenarioError, match="ft_noise_scale: the base scenario's force_sensor.noise_std is zero"
    ):
        parse_campaign(data)
    data = copy.deepcopy(BASE)
    with pytest.raises(ScenarioError, match="campaign: is required"):
        parse_campaign(data)
    with pytest.raises(ScenarioError, match="does not exist"):
        load_campaign(ROOT / "scenarios" / "no_such_campaign.toml")


def test_cells_are_the_product_of_the_axes_with_base_defaults():
    c = parse_campaign(campaign_data(axes={"scanner_noise_scale": [2.0, 0.5], "n_tests": [3, 4, 6]}))
    cells = c.cells()
    assert len(cells) == 6 and c.n_trials == 18
    assert {x.pose_set for x in cells} == {"scenario"} and {x.method for x in cells} == {"fgls"}
    assert {x.ft_noise_scale for x in cells} == {1.0}
    assert [(x.n_tests, x.scanner_noise_scale) for x in cells[:2]] == [(3, 2.0), (3, 0.5)]  # file order kept
    # every nested cell runs on one test list of the largest size
    assert {c.plan_key(x) for x in cells} == {"scenario:6"}


def test_seeds_are_derived_from_the_campaign_seed_only():
    c = parse_campaign(campaign_data(axes={"n_tests": [3, 4], "scanner_noise_scale": [1.0, 2.0]}))
    a, b = c.cells()[0], c.cells()[3]
    expected = int(np.random.SeedSequence(5, spawn_key=(0, 7)).generate_state(1, np.uint64)[0]) >> 1
    assert c.trial_seed(a, 7) == c.trial_seed(b, 7) == expected  # paired: common random numbers
    assert c.trial_seed(a, 7) != c.trial_seed(a, 8)
    unpaired = parse_campaign(
        campaign_data(paired=False, axes={"n_tests": [3, 4], "scanner_noise_scale": [1.0, 2.0]})
    )
    assert unpaired.trial_seed(a, 7) != unpaired.trial_seed(b, 7)
    words = a.hash_words()
    assert (
        unpaired.trial_seed(a, 7)
        == int(np.random.SeedSequence(5, spawn_key=(0, 7, *words)).generate_state(1, np.uint64)[0]) >> 1
    )
    # axis order in the file, trial count and axis values do not change a trial's seed or key
    swapped = parse_campaign(
        campaign_data(trials=9, axes={"scanner_noise_scale": [2.0, 1.0], "n_tests": [4, 3]})
    )
    same = next(x for x in swapped.cells() if x.key == a.key)
    assert swapped.trial_seed(same, 7) == c.trial_seed(a, 7)
    assert swapped.fingerprint == c.fingerprint
    assert parse_campaign(campaign_data(seed=6)).fingerprint != c.fingerprint


def test_noise_scaling_touches_gaussian_and_drift_terms_only():
    base = ScanNoise()
    s = scaled_noise(base, 2.5)
    assert s.range_std_m == pytest.approx(2.5e-5, rel=1e-15)
    assert s.drift_translation_std_m == pytest.approx(2.5 * 3e-6, rel=1e-15)
    assert s.drift_rotation_std_rad == pytest.approx(2.5 * 5e-6, rel=1e-15)
    assert (s.outlier_fraction, s.dropout_start_deg) == (base.outlier_fraction, base.dropout_start_deg)
    c = parse_campaign(campaign_data(axes={"ft_noise_scale": [0.0, 4.0]}))
    assert c.ft_noise_std(c.cells()[1]) == pytest.approx(
        tuple(4 * v for v in c.scenario.force_sensor.noise_std)
    )
