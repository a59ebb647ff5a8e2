"""The world's truth file: the KR60-3's stiffness is the paper's Table 5, and malformed truth
files are refused naming the file and the field."""

import shutil

import numpy as np
import pytest

from vtestbed import robots
from vtestbed.errors import DescriptionError, UnknownNameError
from vtestbed.world.truth import load_truth

# Gao et al. 2023, Table 5 [N*mm/rad], typed from the paper.
TABLE5_NMM = np.array([2.1977e9, 8.9939e8, 1.1118e9, 6.4449e7, 2.5362e7, 1.9978e7])
SOURCE = robots.MODELS_DIR / "kuka_kr60_3"


def test_kr60_truth_is_paper_table5_in_si(truth):
    np.testing.assert_allclose(truth.stiffness_true, TABLE5_NMM / 1000.0, rtol=1e-15)
    assert truth.robot == "kuka_kr60_3" and truth.source == SOURCE / "truth.toml"
    assert len(truth.damping) == len(truth.armature) == 6
    assert min(truth.damping) > 0 and min(truth.armature) > 0


def _joint_table(name, k, damping=1.0, armature=0.1):
    return (
        f'[[joints]]\nname = "{name}"\nstiffness_Nm_per_rad = {k!r}\n'
        f"damping_Nms_per_rad = {damping!r}\narmature_kgm2 = {armature!r}\n"
    )


@pytest.fixture
def models(tmp_path, monkeypatch):
    """A models folder holding a copy of the KR60-3 description; write(truth_text) adds a truth."""
    monkeypatch.setattr(robots, "MODELS_DIR", tmp_path)
    counter = [0]

    def write(text: str) -> str:
        counter[0] += 1
        name = f"kr60_{tmp_path.name}_{counter[0]}"  # unique in the session: load_truth caches by name
        (tmp_path / name).mkdir()
        shutil.copy(SOURCE / "robot.toml", tmp_path / name / "robot.toml")
        (tmp_path / name / "truth.toml").write_text(text)
        return name

    return write


def test_a_truth_file_is_read_in_the_descriptions_joint_order(models):
    k = [1e6, 2e6, 3e6, 4e4, 5e4, 6e4]
    name = models("".join(_joint_table(f"joint{i + 1}", k[i], 10.0 * i, 0.5) for i in range(6)))
    truth = load_truth(name)
    assert np.array_equal(truth.stiffness_true, k)
    assert truth.damping == (0.0, 10.0, 20.0, 30.0, 40.0, 50.0) and truth.armature == (0.5,) * 6


def _six(changes):
    """Six joint tables (joint1..joint6, k = 1e5 N*m/rad) with ``changes[i]`` applied to joint i."""
    rows = []
    for i in range(6):
        args = {"name": f"joint{i + 1}", "k": 1e5} | changes.get(i, {})
        rows.append(_joint_table(**args))
    return "".join(rows)


@pytest.mark.parametrize(
    "text, message",
    [
        ("".join(_joint_table(f"joint{i + 1}", 1e5) for i in range(5)), r"joints must be 6 tables \(\[\[joints\]\]\), one per joint"),
        ('robot = "kuka_kr60_3"\n', r"joints must be 6 tables"),
        ('robot = "x"\n', r"robot = 'x' does not match the description 'kuka_kr60_3'"),
        (_six({2: {"name": "elbow"}}), r"joints must be named \['joint1', .*'joint6'\] in order, got \['joint1', 'joint2', 'elbow'"),
        (_six({3: {"damping": -1.0}}), r"joints\[3\]\.damping_Nms_per_rad must be a finite number >= 0, got -1\.0"),
        (_six({1: {"k": float("inf")}}), r"joints\[1\]\.stiffness_Nm_per_rad must be a finite number >= 0, got inf"),
        (_six({5: {"k": 0.0}}), r"every stiffness_Nm_per_rad must be > 0"),
        (_six({0: {"armature": "heavy"}}), r"joints\[0\]\.armature_kgm2 must be a finite number >= 0"),
        ("[[joints]\n", r"not valid TOML: .*at line 1, column 9"),
    ],
)  # fmt: skip
def test_malformed_truth_names_the_file_and_the_field(models, text, message):
    name = models(text)
    with pytest.raises(DescriptionError, match=rf"{name}/truth\.toml: {message}"):
        load_truth(name)


def test_missing_truth_or_robot_is_named(models, tmp_path):
    name = models("")
    (tmp_path / name / "truth.toml").unlink()
    with pytest.raises(DescriptionError, match=rf"world truth .*{name}/truth\.toml is missing"):
        load_truth(name)
    with pytest.raises(UnknownNameError, match=rf"unknown robot 'ur5'; valid names: {name}"):
        load_truth("ur5")
