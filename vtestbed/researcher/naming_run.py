"""The naming on one reduced dataset, the core ``diagnose`` and the benchmarks' trials share.

The steps, in order: the paper's model (with the baseline statics) fitted to the identification
tests as measured, against the noise floor (the detection); the scanner's scale checked on the
block's declared size and settled (measured, ruled out or left a candidate, :mod:`.scale_term`);
the stepwise naming of the other candidates on the corrected data (:func:`.diagnose.name_effects`).
``discrepancy.diagnose`` builds its report from the result, and ``benchmarks/_discrepancy_worlds.py``
its trial records, so the benchmark measures what the command does. Units: SI.
"""

from __future__ import annotations

from dataclasses import dataclass

from .block_size import SCALE_TOLERANCE_PPM, ScaleCheck, scale_check
from .candidates import ModelContext
from .diagnose import Whitener, fit_model, name_effects
from .model_fit import ModelFit
from .scale_term import ScaleTerm, corrected_context, settle_scale, settled_pool

__all__ = ["NamingRun", "run_naming"]


@dataclass(frozen=True)
class NamingRun:
    """What one naming computed.

    Attributes
    ----------
    ctx, ctx_val : ModelContext
        The identification and the validation tests, as measured.
    white : Whitener
        The noise floor's whitening.
    base : ModelFit
        The paper's model on ``ctx``: the detection's fit and the "before" figures.
    scale : ScaleCheck or None
        The block-size check (None: a mesh target, or fewer than 3 tests with edges).
    term : ScaleTerm or None
        What it settled (None: ``scanner_scale`` not among the candidates).
    pool : list of Candidate
        The candidates the naming tested (``scanner_scale`` left out where the check settled it).
    fixed, fixed_val : ModelContext
        ``ctx`` and ``ctx_val`` with a measured scale corrected (the same objects otherwise).
    chosen, steps, final
        :func:`.diagnose.name_effects`' named terms, its rounds and the final fit.
    """

    ctx: ModelContext
    ctx_val: ModelContext
    white: Whitener
    base: ModelFit
    scale: ScaleCheck | None
    term: ScaleTerm | None
    pool: list
    fixed: ModelContext
    fixed_val: ModelContext
    chosen: list
    steps: list
    final: ModelFit


def run_naming(
    measurements: list,
    setup,
    kin,
    statics,
    floor,
    pool: list,
    alpha: float,
    rank_by: str,
    scale_tolerance_ppm: float = SCALE_TOLERANCE_PPM,
) -> NamingRun:
    """Detect, settle the scale and name, on a reduced dataset.

    Parameters
    ----------
    measurements : list of TestMeasurement
        Every test (identification and validation), with the block's apparent edges where measured.
    setup : DatasetSetup
    kin : ArmKinematics
    statics : ExactStatics or None
        The baseline's statics (``model_file.baseline_statics``).
    floor : NoiseFloor
    pool : list of Candidate
        The candidates, ``scanner_scale`` among them or not.
    alpha : float
        The family-wise level of the naming and the level of the scale check.
    rank_by : str
        How the significant candidates are ranked (:data:`.diagnose.RANK_CRITERIA`).
    scale_tolerance_ppm : float
        The scale check's tolerance [ppm].
    """
    ident = [m for m in measurements if m.group == "identification"]
    valid = [m for m in measurements if m.group == "validation"]
    ctx, ctx_val = ModelContext(ident, setup, kin, statics), ModelContext(valid, setup, kin, statics)
    white = Whitener(floor)
    base = fit_model(ctx, white, [])
    scale = scale_check([m.edge_lengths for m in measurements], setup.block_edge, alpha, scale_tolerance_ppm)
    term = settle_scale(scale, pool)
    tested = settled_pool(term, pool)
    fixed, fixed_val = corrected_context(ctx, term), corrected_context(ctx_val, term)
    chosen, steps, final = name_effects(fixed, white, tested, alpha, rank_by=rank_by)
    return NamingRun(ctx, ctx_val, white, base, scale, term, tested, fixed, fixed_val, chosen, steps, final)
