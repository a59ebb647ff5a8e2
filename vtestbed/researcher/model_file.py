"""The identified model's baseline statics and its file: what ``diagnose`` names, for reuse.

``diagnose`` fits the paper's model on one of two statics (``STATICS``): the clean world's exact
statics (:mod:`.statics`, default) or the paper's linear model, against which the clean world's
three gaps are candidates of their own. It writes the named terms to ``model.json``
(``vtestbed-model/1``: the robot, the statics, the terms and their parameters);
``vtestbed identify --model FILE`` refits the paper's model plus those terms on a dataset
(:func:`identify_with_model`). Researcher side: reads the dataset and the file, never the truth.
Units: SI; stiffness in N*m/rad.
"""

from __future__ import annotations

from ..dataset import read_setup
from ..errors import ConvergenceError, DatasetError, OutOfRangeError, UnknownNameError
from .block_size import scale_check
from .candidates import (
    BLOCK_OFFSET_LABELS,
    CANDIDATE_NAMES,
    CLEAN_WORLD_CANDIDATE_NAMES,
    OPTIONAL_CANDIDATE_NAMES,
    ModelContext,
    candidates,
)
from .diagnose import DEFAULT_ALPHA, Whitener, fit_model, identifiable, require_tests, validation_gap
from .kinematics import ArmKinematics
from .model_fit import scaled_svd
from .scale_term import SCALE_LABEL, corrected, measured, settled_pool, with_measured
from .scan_mean import load_with_floor
from .statics import ExactStatics

STATICS = ("exact", "paper")
DEFAULT_STATICS = "exact"


def require_outside(kind: str, terms, where: str) -> None:
    """The clean world's own gaps are part of the exact statics: fitting them on top is refused."""
    inside = [t for t in terms if t in CLEAN_WORLD_CANDIDATE_NAMES]
    if kind == "exact" and inside:
        raise OutOfRangeError(
            f"{where}: candidate {inside[0]!r} is part of the exact statics baseline, so it cannot be "
            "tested against it; use statics 'paper' to test the clean world's terms "
            f"({', '.join(CLEAN_WORLD_CANDIDATE_NAMES)})"
        )


def require_names(names, where: str) -> None:
    """Candidate names as a user lists them: each a known name, listed once (a name given twice
    would count twice in the search's Bonferroni family and stand in for itself)."""
    valid = CLEAN_WORLD_CANDIDATE_NAMES + CANDIDATE_NAMES + OPTIONAL_CANDIDATE_NAMES
    if not names or not all(names):
        raise OutOfRangeError(
            f"{where}: {','.join(names)!r} holds an empty name; give comma-separated candidate names, "
            f"each one of {', '.join(sorted(valid))}"
        )
    unknown = [n for n in names if n not in valid]
    if unknown:
        raise UnknownNameError("candidate", unknown[0], valid, where)
    twice = next((n for k, n in enumerate(names) if n in names[:k]), None)
    if twice is not None:
        raise OutOfRangeError(f"{where}: candidate {twice!r} is listed twice; list each candidate once")


def baseline_statics(kind: str, kin, setup):
    """The base model's statics: ``exact`` (the clean world's, :mod:`.statics`) or the paper's."""
    if kind not in STATICS:
        raise UnknownNameError("statics", kind, STATICS)
    return ExactStatics(kin, setup) if kind == "exact" else None


def default_candidates(statics: str) -> tuple[str, ...]:
    """The default candidate names: against the paper's statics, the clean world's three gaps too."""
    return (CLEAN_WORLD_CANDIDATE_NAMES if statics == "paper" else ()) + CANDIDATE_NAMES


MODEL_FORMAT = "vtestbed-model/1"
# Labels that model files wrote before the term was split into parts (2026-11-29): read as all of them
SPLIT_TERMS = {"block_offset": tuple(BLOCK_OFFSET_LABELS.values())}


def model_file(report: dict, robot: str, statics: str = DEFAULT_STATICS) -> dict:
    """The identified model as a file records it: the robot, its statics and the named terms."""
    return {"format": MODEL_FORMAT, "robot": robot, "statics": statics, "terms": list(report["named"]),
            "parameters": report["model"]["parameters"]}  # fmt: skip


def read_model(path, robot, kin) -> tuple[list, str]:
    """The candidate terms a model file names, checked against the dataset's robot, and its statics."""
    from ..files import read_json

    data = read_json(path, "model file", DatasetError)
    if data.get("format") != MODEL_FORMAT:
        raise DatasetError(f"{path}: format must be {MODEL_FORMAT!r}, got {data.get('format')!r}")
    if data.get("robot") != robot:
        raise DatasetError(
            f"{path}: robot = {data.get('robot')!r} does not match the dataset's robot {robot!r}"
        )
    pool = {c.label: c for c in candidates(kin, default_candidates("paper") + OPTIONAL_CANDIDATE_NAMES)}
    terms = data.get("terms")
    if not isinstance(terms, list) or not all(isinstance(t, str) for t in terms):
        raise DatasetError(f"{path}: terms must be a list of candidate labels")
    terms = [part for t in terms for part in SPLIT_TERMS.get(t, (t,))]
    unknown = [t for t in terms if t not in pool]
    if unknown:
        raise DatasetError(f"{path}: terms: unknown term {unknown[0]!r}; valid terms: {', '.join(pool)}")
    statics = data.get("statics", DEFAULT_STATICS)
    if statics not in STATICS:
        raise DatasetError(f"{path}: statics = {statics!r}; valid: {', '.join(STATICS)}")
    require_outside(statics, [pool[t].name for t in terms], f"{path}: terms (statics = 'exact')")
    return [pool[t] for t in terms], statics


def identify_with_model(root, model_path) -> dict:
    """Identify the stiffness with the paper's model plus a model file's terms (needs repeat scans).

    A ``scanner_scale`` term is measured on the block wherever the dataset's scans allow the
    scale check (:mod:`.scale_term`: the translations divided by ``1 + s``, whatever the check's
    verdict, since the model says the scale is there), and fitted to the displacements otherwise
    (a mesh target, fewer than 3 tests).
    """
    setup = read_setup(root)  # the robot the model file must match, before the clouds are fitted
    kin = ArmKinematics.for_setup(setup)
    terms, statics = read_model(model_path, setup.robot, kin)
    with_scale = any(t.label == SCALE_LABEL for t in terms)  # only then the block's edges are measured
    setup, measurements, floor = load_with_floor(root, edges=with_scale)  # as diagnose measures
    scale = None
    if with_scale:
        scale = measured(scale_check([m.edge_lengths for m in measurements], setup.block_edge, DEFAULT_ALPHA))
    terms, measurements = settled_pool(scale, terms), corrected(measurements, scale)
    exact = baseline_statics(statics, kin, setup)
    ident = [m for m in measurements if m.group == "identification"]
    valid = [m for m in measurements if m.group == "validation"]
    ctx, white = ModelContext(ident, setup, kin, exact), Whitener(floor)
    require_tests(root, len(ident), kin.robot.dof, sum(len(t.params) for t in terms),
                  f"the model's {len(terms)} terms", "Record more tests or name fewer terms in the model file")  # fmt: skip
    base = fit_model(ctx, white, [])
    terms = identifiable(ctx, white, terms, base.compliance)
    try:
        fit = _fit_determined(ctx, white, terms, base, model_path, root)
        gap = validation_gap(ModelContext(valid, setup, kin, exact), white, fit, terms)
    except ConvergenceError as exc:  # compliances far off (too many terms for the tests): no statics
        raise DatasetError(
            f"{model_path}: terms: the paper's model plus {', '.join(t.label for t in terms)} fitted to the "
            f"{len(ident)} identification tests of {root} predicts nothing physical ({exc}); name fewer "
            "terms in the model file or record more tests"
        ) from None
    return {"model": with_measured(fit.to_dict(), scale), "joint_names": list(kin.robot.joint_names),
            "validation": gap}  # fmt: skip


# The scaled columns' condition number above which a model's parameters are not determined: every
# single candidate on the paper's tests is below 50, ten terms together below 250; a term that
# nearly repeats another (a geometric error's dtheta6 beside the sensor's yaw and the block's rz)
# jumps to 1e11.
COLLINEAR_CONDITION = 1e6


def _condition(fit) -> float:
    """The condition number of ``fit``'s whitened design, its columns scaled to unit norm."""
    s = scaled_svd(fit.design)[1]
    return float(s[0] / s[-1])


def _fit_determined(ctx, white, terms, base, model_path, root):
    """The fit of ``base`` plus ``terms``, each of which must add as many directions as it has
    parameters, or least squares would split the shared ones by minimum norm and report a small
    std. diagnose's search never names a term that adds no direction (its likelihood ratio has no
    degree of freedom); a model file written by hand can; and when a later term contains an
    earlier one (link 2 contains ``joint_coupling(2,3)``), the search's backward step drops the
    earlier one (df 0). The terms are added one at a time; the last fit is the model's."""
    fit = base
    if (cond := _condition(base)) > COLLINEAR_CONDITION:  # the tests alone: no term to blame
        raise DatasetError(
            f"{root}: the stiffnesses alone are nearly collinear on its tests (condition number of the scaled "
            f"columns {cond:.2g}, valid: below {COLLINEAR_CONDITION:g}): the tests do not determine "
            "them, let alone the model file's terms; add tests at other poses (vtestbed poses design)"
        )
    for k, term in enumerate(terms):
        grown = fit_model(ctx, white, terms[: k + 1])
        if grown.rank - fit.rank < len(term.params):
            shared = len(term.params) - (grown.rank - fit.rank)
            earlier = ", ".join(t.label for t in terms[:k]) or "no term"
            raise DatasetError(
                f"{model_path}: terms: {term.label!r} shares {shared} of its {len(term.params)} directions "
                f"with the stiffnesses and {earlier} on these tests, so its parameters are not determined; "
                "leave it out (or the term it duplicates)"
            )
        if (cond := _condition(grown)) > COLLINEAR_CONDITION:
            earlier = ", ".join(t.label for t in terms[:k]) or "no term"
            raise DatasetError(
                f"{model_path}: terms: {term.label!r} is nearly collinear with the stiffnesses and {earlier} "
                f"on these tests (condition number of the scaled columns {cond:.2g}, valid: below "
                f"{COLLINEAR_CONDITION:g}), so its parameters are not determined (they would come out "
                "arbitrarily large, with stds to match); leave it out (or the term it duplicates), or add "
                "tests that separate them"
            )
        fit = grown
    return fit
