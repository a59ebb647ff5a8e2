"""The ``scanner_scale`` candidate settled by the block's size, before the stiffness fit sees it.

The stiffness model tells a scanner scale error from stiffer joints only by the rotations, which
the scale leaves alone: near the naming's detection limit (about 60-90 times the realistic 100
ppm) a block offset's translation reproduces 95 % of its pattern, and after one round of
discrimination tests 6 of 150 seeds still named the wrong one (docs/discrepancy.md). The block's
apparent edges (:mod:`.block_size`) measure the scale directly, with a standard error of about
9 ppm over the paper's tests. So where that check decides, the naming does not test the
candidate (:func:`settle_scale`):

- **beyond** the tolerance: the scale is *measured*. The scanner scales every coordinate by
  ``1 + s``, so the block frame's translations and with them every displacement's translation
  (``TestMeasurement.displacement[:3]``) by ``1 + s``; rotations are unchanged. Each displacement's
  translation is divided by ``1 + s``, ``scanner_scale`` is named with ``s`` and the check's
  standard error, and the other candidates are tested on the corrected data.
- **within** it: the candidate is ruled out and leaves the candidates (one fewer in the
  Bonferroni family). What the check rules out (the tolerance plus its interval, about 1030 ppm)
  lies far below what the stiffness fit could name.
- **neither**, or not checked (a mesh target, fewer than 3 tests): the candidate stays a fitted
  term, as before the check existed.

Choices: the check assumes the block is the size setup.json declares (a block 0.1 % larger reads
as a +1000 ppm scale); the noise floor's translations carry the same ``1 + s`` and are left
alone (at 1 % scale a 1 % error in their std). A user who leaves ``scanner_scale`` out of the
candidates gets the check as a report only. Units: the scale is dimensionless (``s``), ppm where
named so.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

from .block_size import ScaleCheck

SCALE_LABEL = "scanner_scale"  # the candidate's label and name (candidates._scanner_scale)
SCALE_PARAM = "scale"
SCALE_ACTIONS = ("measured", "ruled_out", "tested")  # beyond / within the tolerance / neither


@dataclass(frozen=True)
class ScaleTerm:
    """What the scale check decided for the candidate ``scanner_scale``.

    Attributes
    ----------
    action : str
        One of :data:`SCALE_ACTIONS`.
    scale, std : float
        The scale the displacements' translations were divided by (``1 + scale``) and its standard
        error [1]; 0 unless ``action == "measured"``.
    bound_ppm : float or None
        With ``"ruled_out"``: the scale beyond which the check rules it out (95 %) [ppm].
    """

    action: str
    scale: float = 0.0
    std: float = 0.0
    bound_ppm: float | None = None

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> ScaleTerm:
        return cls(**data)

    def sentence(self) -> str:
        """What the naming did with the candidate, one sentence for the report."""
        if self.action == "measured":
            return (f"So `{SCALE_LABEL}` is named from the block, s = {self.scale * 1e6:+.0f} +- "
                    f"{self.std * 1e6:.0f} ppm: every displacement's translation is divided by 1 + s "
                    "before the other candidates are tested.")  # fmt: skip
        if self.action == "ruled_out":
            return (f"So `{SCALE_LABEL}` is left out of the candidates tested: the stiffness fit could "
                    f"not name a scale below {self.bound_ppm:.0f} ppm (its 50 % size is several times that).")  # fmt: skip
        return f"So `{SCALE_LABEL}` stays a candidate, tested like the others on the displacements."


def settle_scale(check: ScaleCheck | None, pool: list) -> ScaleTerm | None:
    """The candidate's fate under ``check``; None when ``pool`` (candidate terms) has no
    ``scanner_scale`` (the user left it out: the check is then a report only)."""
    if not any(c.label == SCALE_LABEL for c in pool):
        return None
    if check is None:
        return ScaleTerm("tested")
    if check.beyond:
        return measured(check)
    far = max(abs(v) for v in check.interval_ppm)
    if far <= check.tolerance_ppm:  # the check's "within": ScaleCheck.sentence
        return ScaleTerm("ruled_out", bound_ppm=far + check.tolerance_ppm)
    return ScaleTerm("tested")


def measured(check: ScaleCheck | None) -> ScaleTerm | None:
    """The scale as the check measures it, whatever its verdict (a model file that names the
    scale: :func:`.model_file.identify_with_model`); None without a check."""
    return None if check is None else ScaleTerm("measured", check.scale_ppm * 1e-6, check.std_ppm * 1e-6)


def is_measured(term: ScaleTerm | None) -> bool:
    """Whether the scale was measured on the block (the translations corrected, the term named)."""
    return term is not None and term.action == "measured"


def settled_pool(term: ScaleTerm | None, pool: list) -> list:
    """The candidates the naming still tests: without ``scanner_scale`` where the check decided."""
    if term is None or term.action == "tested":
        return list(pool)
    return [c for c in pool if c.label != SCALE_LABEL]


def corrected(measurements: list, term: ScaleTerm | None) -> list:
    """The measurements with each displacement's translation divided by ``1 + s`` where the scale
    is measured (unchanged otherwise)."""
    if not is_measured(term):
        return list(measurements)
    out = []
    for m in measurements:
        d = m.displacement.copy()
        d[:3] /= 1.0 + term.scale
        out.append(replace(m, displacement=d))
    return out


def corrected_context(ctx, term: ScaleTerm | None):
    """A ``candidates.ModelContext`` of the :func:`corrected` measurements; ``ctx`` itself (its
    cached columns kept) where the scale is not measured."""
    if not is_measured(term):
        return ctx
    return type(ctx)(corrected(ctx.measurements, term), ctx.setup, ctx.kin, ctx.statics)


def with_measured(model: dict, term: ScaleTerm | None) -> dict:
    """A fit's ``to_dict`` with a measured scale as its first term (its parameter and std)."""
    if not is_measured(term):
        return model
    return {**model, "terms": [SCALE_LABEL, *model["terms"]],
            "parameters": {SCALE_LABEL: {SCALE_PARAM: term.scale}, **model["parameters"]},
            "parameters_std": {SCALE_LABEL: {SCALE_PARAM: term.std}, **model["parameters_std"]}}  # fmt: skip


def named_labels(labels: list, term: ScaleTerm | None) -> list:
    """The named terms' labels, a measured scale first."""
    return [SCALE_LABEL, *labels] if is_measured(term) else list(labels)


def report_scale(report: dict) -> ScaleTerm | None:
    """What a diagnosis report settled for the scale (its ``scale_term``; None: no
    ``scanner_scale`` candidate, or a report from before the check settled it)."""
    term = report.get("scale_term")
    return ScaleTerm.from_dict(term) if term else None


def named_note(report: dict, label: str) -> str:
    """What a report says beside a named ``label``: for a scale measured on the block, that it was
    (the likelihood ratio did not name it); else nothing."""
    # an older report (the check a report only) has no scale_term
    if label == SCALE_LABEL and is_measured(report_scale(report)):
        return " (measured on the block's size, not by likelihood ratio)"
    return ""
