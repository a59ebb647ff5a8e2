"""Experiment design on the nominal model: which poses and loads to test.

:func:`criterion` and :func:`optimize` are the paper's kappa(J_AW) criterion and its optimum;
:func:`joint_plane_map`, :func:`find_regions` and :func:`sample_poses` its high-criterion regions
(Z1..Z4); :func:`joint_influence` the joints' influence (paper Table 2); :func:`candidate_tests`,
:func:`select_tests` and :func:`evaluate` the D/A/E/minimax-optimal choice of tests, which needs an
explicit stiffness prior (:mod:`vtestbed.design.priors`); :func:`candidate_pool` the feasible test
space, :func:`design` the minimax (default) design with its convex relaxation and certified lower
bound (:mod:`vtestbed.design.minimax`), :func:`refine_design` that design with the pool grown around its
poses (:mod:`vtestbed.design.refine`), :func:`next_tests` the sequential design after a dataset,
:func:`stiffness_bound` the Cramer-Rao bound from the scanner's point noise
(:mod:`vtestbed.design.crlb`). Nominal geometry only, no truth.
"""

from .crlb import StiffnessBound, frame_covariance, nominal_scan, pose_covariances, stiffness_bound
from .influence import Influence, joint_influence
from .kappa import CriterionValue, Optimum, criterion, inv_kappa_batch, optimize, paper_optimum
from .minimax import MinimaxDesign, Relaxation, design, relax
from .optimal import CandidateTest, DesignReport, Selection, candidate_tests, evaluate, select_tests
from .pool import PoolOptions, TestPool, candidate_pool, kappa_selection, random_poses
from .priors import NAMED_PRIORS, PAPER_TABLE5, StiffnessPrior, stiffness_prior
from .refine import RefinedDesign, refine_design
from .regions import PoseConstraints, PoseSet, Region, find_regions, joint_plane_map, sample_poses
from .sequential import NextTests, next_tests

__all__ = [
    "NAMED_PRIORS",
    "PAPER_TABLE5",
    "CandidateTest",
    "CriterionValue",
    "DesignReport",
    "Influence",
    "MinimaxDesign",
    "NextTests",
    "Optimum",
    "PoolOptions",
    "PoseConstraints",
    "PoseSet",
    "RefinedDesign",
    "Region",
    "Relaxation",
    "Selection",
    "StiffnessBound",
    "StiffnessPrior",
    "TestPool",
    "candidate_pool",
    "candidate_tests",
    "criterion",
    "design",
    "evaluate",
    "find_regions",
    "frame_covariance",
    "inv_kappa_batch",
    "joint_influence",
    "joint_plane_map",
    "kappa_selection",
    "next_tests",
    "nominal_scan",
    "optimize",
    "paper_optimum",
    "pose_covariances",
    "random_poses",
    "refine_design",
    "relax",
    "sample_poses",
    "select_tests",
    "stiffness_bound",
    "stiffness_prior",
]
