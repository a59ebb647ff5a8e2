import mujoco
import numpy as np
import pytest

from vtestbed.robots import available_robots, load_robot, robot_dir
from vtestbed.world import mjcf


@pytest.mark.parametrize("name", available_robots())
def test_committed_xml_is_what_the_generator_produces(name):
    robot = load_robot(name)
    directory = robot_dir(name)
    for file, text in mjcf.model_files(robot).items():
        committed = (directory / file).read_text()
        assert committed == text, (
            f"{name}/{file} drifted from the generator: run `vtestbed models --robot {name}`"
        )


def test_committed_scene_loads_with_the_described_physics(robot, truth, lab):
    model = mujoco.MjModel.from_xml_path(str(robot_dir(robot.name) / "scene.xml"))
    assert model.nq == 6
    for i, joint in enumerate(robot.joints):
        j = model.joint(joint.name)
        assert j.qposadr[0] == i
        assert model.jnt_stiffness[j.id] == truth.stiffness[i]
        # MjSpec.to_xml writes 6 significant digits; the rig compiles the spec at full precision
        np.testing.assert_allclose(model.jnt_range[j.id], [joint.lower, joint.upper], atol=5e-6)
        assert model.body(f"link{i + 1}").mass[0] == joint.mass
    tool_mass = model.body_subtreemass[model.body(mjcf.TOOL_BODY).id]
    expected = lab.sensor.mass_tool_side + lab.block.stem_mass + lab.block.edge**3 * lab.block.density
    assert abs(tool_mass - expected) < 1e-12
    # the robot alone also loads, and has no wire
    bare = mujoco.MjModel.from_xml_path(str(robot_dir(robot.name) / "kr60_3.xml"))
    assert bare.nq == 6 and bare.ntendon == 0
