"""The truth world (MuJoCo): what the virtual lab really does, and what only it knows.

A :class:`Rig` is the robot with torsion-spring joints of true stiffness (:class:`RobotTruth`),
the force sensor, the target block, the table with rings and the wire; a :class:`Scanner`
ray-casts it and :class:`ScanNoise` adds the scanner's errors; :class:`ForceTorqueSensor` reads
the wrench. :func:`run_test_physics` and :func:`draw_readings` are one test, as every path
(simulate, Monte Carlo, feasibility checks) runs it.

The researcher's side (:mod:`vtestbed.researcher`) never imports this package: only measurements
cross, through a dataset (:mod:`vtestbed.dataset`). Units: SI, poses in the robot base frame.
"""

from .effects import EFFECTS, WorldEffect
from .mjcf import SceneEffect, build_robot_spec, build_scene_spec, model_files, write_model_files
from .physics import TestPhysics, draw_readings, run_test_physics, test_rng
from .repeats import draw_repeat_scans, repeat_rng
from .rig import Rig
from .rig_state import RigState
from .scan_noise import NoisyScan, ScanGeometry, ScanNoise, scaled_noise
from .scanner import Scanner
from .sensors import ForceTorqueSensor
from .truth import RobotTruth, load_truth

__all__ = [
    "EFFECTS",
    "ForceTorqueSensor",
    "NoisyScan",
    "Rig",
    "RigState",
    "RobotTruth",
    "WorldEffect",
    "ScanGeometry",
    "ScanNoise",
    "Scanner",
    "SceneEffect",
    "TestPhysics",
    "build_robot_spec",
    "build_scene_spec",
    "draw_readings",
    "draw_repeat_scans",
    "load_truth",
    "model_files",
    "repeat_rng",
    "run_test_physics",
    "scaled_noise",
    "test_rng",
    "write_model_files",
]
