"""Bad robot input (docs/errors.md, "Robot descriptions and lab imports"): a URDF whose inertia
MuJoCo would refuse is refused before anything is written (the import is atomic), and a
hand-edited ``models/<robot>/robot.toml`` is checked when it is loaded: one line naming the file
and the field, exit 2, no traceback."""

from __future__ import annotations

import math

import pytest

from vtestbed import robots
from vtestbed.cli.main import main
from vtestbed.world import truth as world_truth

# A plain 6R arm (axes z, y, y, x, y, x): joint origins [m] in the parent link, one per joint
CHAIN = [("0 0 0.3", "0 0 1"), ("0.1 0 0.2", "0 1 0"), ("0 0 0.5", "0 1 0"),
         ("0.2 0 0.1", "1 0 0"), ("0.3 0 0", "0 1 0"), ("0.1 0 0", "1 0 0")]  # fmt: skip
GOOD = 'ixx="0.02" ixy="0" ixz="0" iyy="0.03" iyz="0" izz="0.04"'


def _urdf(path, inertia=None):
    """The arm, every link 2 kg with inertia ``GOOD``; ``inertia`` maps a link to its own."""
    inertia = inertia or {}

    def link(name):
        tensor = inertia.get(name, GOOD)
        return (f'<link name="{name}"><inertial><origin xyz="0.01 0 0"/><mass value="2"/>'
                f"<inertia {tensor}/></inertial></link>")  # fmt: skip

    parts = ['<robot name="plain6">', link("l0")]
    for i, (xyz, axis) in enumerate(CHAIN, 1):
        parts += [
            f'<joint name="j{i}" type="revolute"><parent link="l{i - 1}"/><child link="l{i}"/>'
            f'<origin xyz="{xyz}"/><axis xyz="{axis}"/>'
            '<limit lower="-2" upper="2.5" effort="100" velocity="1"/></joint>',
            link(f"l{i}"),
        ]
    parts += ['<joint name="bolt" type="fixed"><parent link="l6"/><child link="tool"/>'
              '<origin xyz="0.05 0 0"/></joint><link name="tool"/></robot>']  # fmt: skip
    path.write_text("".join(parts))
    return path


@pytest.fixture
def models(tmp_path, monkeypatch):
    """An empty scratch models folder (the loaders' caches cleared before and after)."""
    folder = tmp_path / "models"
    folder.mkdir()
    monkeypatch.setattr(robots, "MODELS_DIR", folder)
    robots.load_robot.cache_clear()
    world_truth.load_truth.cache_clear()
    yield folder
    robots.load_robot.cache_clear()
    world_truth.load_truth.cache_clear()


def _error(argv, capsys) -> str:
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and err.count("\n") == 1, err
    return err.strip()


def test_a_negative_link_inertia_is_refused_and_nothing_is_written(tmp_path, models, capsys):
    urdf = _urdf(tmp_path / "neg.urdf", {"l1": 'ixx="-0.1" ixy="0" ixz="0" iyy="0.03" iyz="0" izz="0.04"'})
    err = _error(["robot", "import", urdf, "--name", "t_neg", "--tip", "tool"], capsys)
    # the principal moments of diag(-0.1, 0.03, 0.04), in order
    assert err == (
        f"vtestbed: error: {urdf}: link 'l1' <inertial><inertia>: ixx=-0.1 ixy=0 ixz=0 iyy=0.03 iyz=0"
        " izz=0.04 is not a physical inertia: principal moments [-0.1, 0.03, 0.04] kg*m^2 must be >= 0"
        " and each at most the sum of the other two"
    )
    assert list(models.iterdir()) == []  # no models/t_neg, no staging folder
    assert "t_neg" not in _error(["load", "--robot", "t_neg"], capsys).split("valid names:")[1]


def test_an_inertia_breaking_the_triangle_inequality_is_refused(tmp_path, models, capsys):
    # 0.01 + 0.01 < 0.05: no mass distribution has these principal moments
    urdf = _urdf(tmp_path / "tri.urdf", {"l4": 'ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.05"'})
    err = _error(["robot", "import", urdf, "--name", "t_tri", "--tip", "tool"], capsys)
    assert "link 'l4' <inertial><inertia>" in err and "principal moments [0.01, 0.01, 0.05] kg*m^2" in err
    assert list(models.iterdir()) == []


def test_a_moving_body_without_rotational_inertia_is_refused(tmp_path, models, capsys):
    # a point mass at its link's com is a valid URDF link, but alone on joint 3 MuJoCo refuses it
    urdf = _urdf(tmp_path / "point.urdf", {"l3": 'ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"'})
    err = _error(["robot", "import", urdf, "--name", "t_point", "--tip", "tool"], capsys)
    assert err == (
        f"vtestbed: error: {urdf}: the links moved by joint 'j3', lumped, have an inertia that has"
        " principal moments [0, 0, 0] kg*m^2; all must be > 0; MuJoCo needs a physical inertia for"
        " every moving body"
    )
    assert list(models.iterdir()) == []


def test_a_good_import_writes_the_whole_folder_and_force_keeps_other_files(tmp_path, models, capsys):
    urdf = _urdf(tmp_path / "ok.urdf")
    assert main(["robot", "import", str(urdf), "--name", "t_ok", "--tip", "tool"]) == 0
    files = ["README.md", "robot.toml", "scene.xml", "t_ok.xml", "truth.toml"]
    assert [p.name for p in models.iterdir()] == ["t_ok"]  # the staging folder is gone
    assert sorted(p.name for p in (models / "t_ok").iterdir()) == files
    assert robots.load_robot("t_ok").total_mass == pytest.approx(14.0)  # 7 links of 2 kg
    assert "exists already; pass --force" in _error(
        ["robot", "import", urdf, "--name", "t_ok", "--tip", "tool"], capsys
    )
    (models / "t_ok" / "notes.txt").write_text("mine")
    assert main(["robot", "import", str(urdf), "--name", "t_ok", "--tip", "tool", "--force"]) == 0
    assert sorted(p.name for p in (models / "t_ok").iterdir()) == sorted([*files, "notes.txt"])


# hand edits of a good robot.toml: (text replaced, replacement, the error after the file's name)
EDITS = [
    ("\nmass_kg = 2.0", "\nmass_kg = -9.9",
     "joints[0].mass_kg must be a finite number > 0 kg (a moving link), got -9.9"),
    ("controller_limits_deg = [-114.59155902616465", "controller_limits_deg = [nan",
     "joints[0].controller_limits_deg must be 2 finite numbers, got [nan, 143.2394487827058]"),
    ("controller_limits_deg = [-114.59155902616465, 143.2394487827058]", "controller_limits_deg = [30.0, 10.0]",
     "joints[0].controller_limits_deg must be [lower, upper] deg with lower < upper, got [30.0, 10.0]"),
    ("d_m = ", "d_m = inf  # ", "joints[0].d_m must be a finite number, got inf"),
    ("inertia_diag_kgm2 = [", "inertia_diag_kgm2 = [-1.0, 0.5, 0.7]  # [",
     "joints[0]: the inertia (inertia_diag_kgm2, inertia_offdiag_kgm2) has principal moments"),
    ("base_mass_kg = 2.0", "base_mass_kg = -1.0", "base_mass_kg must be a finite number >= 0 kg, got -1.0"),
]  # fmt: skip


@pytest.mark.parametrize("old, new, message", EDITS)
def test_a_hand_edited_description_is_checked_on_load(tmp_path, models, capsys, old, new, message):
    assert main(["robot", "import", str(_urdf(tmp_path / "ok.urdf")), "--name", "t_ed", "--tip", "tool"]) == 0
    capsys.readouterr()
    path = models / "t_ed" / "robot.toml"
    text = path.read_text()
    assert text.count(old) >= 1, old
    path.write_text(text.replace(old, new, 1))
    robots.load_robot.cache_clear()
    for argv in (
        ["robot", "--robot", "t_ed"],
        ["load", "--robot", "t_ed", "--q-deg", "0,0.5,0.5,0.5,0.5,0.5"],
    ):
        err = _error(argv, capsys)
        assert err.startswith(f"vtestbed: error: {path}: {message}"), err


def test_the_shipped_descriptions_pass_the_checks():
    for name in ("kuka_kr60_3", "ur10"):
        robot = robots.robot_from_file(robots.MODELS_DIR / name / "robot.toml")
        assert all(j.mass > 0 and j.lower < j.upper for j in robot.joints)
        assert all(robots.inertia_problem(j.inertia) is None for j in robot.joints)
        assert not math.isnan(robot.total_mass)
