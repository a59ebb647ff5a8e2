"""Experiment design on the nominal model: which poses and loads to test.

:func:`criterion` and :func:`optimize` are the paper's kappa(J_AW) criterion and its optimum;
:func:`joint_plane_map`, :func:`find_regions` and :func:`sample_poses` its high-criterion regions
(Z1..Z4); :func:`joint_influence` the joints' influence (paper Table 2); :func:`candidate_tests`,
:func:`select_tests` and :func:`evaluate` the D/A/E-optimal choice of tests, which needs an
explicit stiffness prior (:mod:`vtestbed.design.priors`). Nominal geometry only, no truth.
"""

from .influence import Influence, joint_influence
from .kappa import CriterionValue, Optimum, criterion, inv_kappa_batch, optimize, paper_optimum
from .optimal import CandidateTest, DesignReport, Selection, candidate_tests, evaluate, select_tests
from .priors import NAMED_PRIORS, PAPER_TABLE5, StiffnessPrior, stiffness_prior
from .regions import PoseConstraints, PoseSet, Region, find_regions, joint_plane_map, sample_poses

__all__ = [
    "NAMED_PRIORS",
    "PAPER_TABLE5",
    "CandidateTest",
    "CriterionValue",
    "DesignReport",
    "Influence",
    "Optimum",
    "PoseConstraints",
    "PoseSet",
    "Region",
    "Selection",
    "StiffnessPrior",
    "candidate_tests",
    "criterion",
    "evaluate",
    "find_regions",
    "inv_kappa_batch",
    "joint_influence",
    "joint_plane_map",
    "optimize",
    "paper_optimum",
    "sample_poses",
    "select_tests",
    "stiffness_prior",
]
