"""The researcher's side (Pinocchio + open3d): from a measurement dataset to joint stiffness.

Everything here reads a dataset (:mod:`vtestbed.dataset`: setup.json, tests.csv, PLY clouds) and
the robot's nominal description, never the world: it does not import :mod:`vtestbed.world` or
mujoco and never sees the truth (``tests/test_architecture.py`` enforces both), so it runs
unchanged on a dataset recorded in a real lab.

The chain: :func:`fit_block_frame` (three planes of the block in a cloud) ->
:func:`measure_test` (displacement, wrench and Jacobian of one test, block frame) ->
:func:`identify` (``delta_d = A c`` by least squares, with an honest covariance) ->
:func:`convergence` / :func:`validation` (the paper's Figures 10 and 11). The discrepancy
workflow: :func:`estimate_noise_floor` (repeat scans), :func:`load_with_floor` (every displacement
against its test's mean unloaded scan, with the floor for it) and :func:`diagnose` (detect, name, add
the effects the paper's model misses; candidate terms in :mod:`.candidates`, the clean world's
exact statics in :mod:`.statics`, the scanner's scale from the block's size in :mod:`.block_size`
and what the naming makes of it in :mod:`.scale_term`). Units: SI.
"""

from .block_size import ScaleCheck, scale_check
from .candidates import Candidate, candidates
from .cloud import BlockFrame, FitParams, fit_block_frame
from .discrepancy import diagnose
from .identify import IdentificationResult, a_matrix, identify, identify_prefixes
from .kinematics import ArmKinematics, build_pinocchio_model
from .measure import (
    TestMeasurement,
    identify_measurements,
    load_measurements,
    measure_arrays,
    measure_test,
    predict_displacement,
    wrench_at_block,
)
from .noise_floor import NoiseFloor
from .repeat_scans import estimate_noise_floor
from .report import convergence, plot_convergence, plot_validation, validation
from .scale_term import ScaleTerm, settle_scale
from .scan_mean import against_scan_mean, load_with_floor
from .statics import ExactStatics

__all__ = [
    "ArmKinematics",
    "BlockFrame",
    "Candidate",
    "ExactStatics",
    "NoiseFloor",
    "ScaleCheck",
    "ScaleTerm",
    "FitParams",
    "IdentificationResult",
    "TestMeasurement",
    "a_matrix",
    "against_scan_mean",
    "build_pinocchio_model",
    "candidates",
    "convergence",
    "diagnose",
    "estimate_noise_floor",
    "fit_block_frame",
    "identify",
    "identify_measurements",
    "identify_prefixes",
    "load_measurements",
    "load_with_floor",
    "measure_arrays",
    "measure_test",
    "plot_convergence",
    "plot_validation",
    "predict_displacement",
    "scale_check",
    "settle_scale",
    "validation",
    "wrench_at_block",
]
