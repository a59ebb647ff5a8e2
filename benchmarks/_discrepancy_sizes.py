"""The sizes "near the detection limit" of ``bench_discrepancy.py``: the factor f_lim on each
effect's size at which its naming test has a given power, and the candidates' overlap.

The noise-free noncentrality of the effect's own naming test (:func:`strength`) is searched in f
(:func:`calibrate`, a secant search on log f) towards the value at which the test has
``--limit-power`` against the trials' estimated floor
(:func:`vtestbed.researcher.floor_calibration.lr_power`). ``bench_discrepancy.py``'s docstring
states the definition in full. Units: SI.
"""

from __future__ import annotations

import math

import _discrepancy_worlds
import numpy as np
from _discrepancy_worlds import ALPHA, max_factor, model_context, noise_free, prepared_world
from scipy.optimize import brentq
from scipy.stats import chi2 as chi2_dist
from scipy.stats import ncx2

from vtestbed.errors import VtestbedError
from vtestbed.researcher.diagnose import Whitener, fit_model, identifiable
from vtestbed.researcher.floor_calibration import lr_power
from vtestbed.researcher.identify import stack
from vtestbed.researcher.noise_floor import NoiseFloor
from vtestbed.scenario import load_scenario
from vtestbed.world.effects import EFFECTS

LIMIT_POWER = 0.5  # "near the detection limit" by default: theoretical power of the naming test
LIMIT_TOL = math.log(1.2)  # |log(lambda / lambda*)| accepted by the secant search


def strength(name: str, factor: float, white: Whitener, statics: str) -> dict:
    """Noise-free noncentrality of the naming test (or of detection, without a candidate).

    Every test of the world is reduced, the validation tests too: a size at which the researcher
    cannot reduce some test's scans (the block leaves its nominal pose) raises here, so the size
    search stays below it (a balancer at x29 once lost validation test V004's +x face).
    """
    prepared, pool = prepared_world(name, factor)
    measured = noise_free(prepared, list(prepared.tests))
    ctx = model_context([m for m in measured if m.group == "identification"], prepared, statics)
    base = fit_model(ctx, white, [])
    family = [c for c in pool if c.name == name]
    if not family:
        return {"lambda": base.chi2, "df": base.dof, "test": "detection", "level": ALPHA, "label": None}
    family = identifiable(ctx, white, family, base.compliance)  # the parameters the search tests
    fits = [(base.chi2 - (fit := fit_model(ctx, white, [c])).chi2, c, fit) for c in family]
    lam, cand, fit = max(fits, key=lambda x: x[0])
    df = fit.rank - base.rank
    signal, power_args = lr_power_inputs(
        white, base, fit, cand.label, df, len(prepared.tests), ALPHA / len(pool)
    )
    return {"lambda": float(lam), "df": df, "test": "naming", "level": ALPHA / len(pool),
            "label": cand.label, "signal": signal, "power_args": power_args}  # fmt: skip


def lr_power_inputs(white: Whitener, without, fit, label: str, df: int, n_tests: int, level: float):
    """What :func:`~vtestbed.researcher.floor_calibration.lr_power` needs to test ``label`` in
    ``fit`` beyond the model ``without`` it: the latter's noise-free residual in the true floor's
    coordinates (noise N(0, I), so without the Whitener's division by sqrt(inflation)), and the
    arguments after it, with the trials' floor sample count (REPEATS of each of ``n_tests``,
    validation tests included). Returns (signal, args): ``lr_power(signal, *args)``."""
    signal = white(without.residuals.reshape(-1)) * math.sqrt(white.inflation)
    tested = np.array([t == label for t in fit.column_terms])
    return signal, (fit.design, tested, df, _discrepancy_worlds.REPEATS * n_tests, level)


def estimated_floor_power(s: dict, scale: float = 1.0) -> float | None:
    """Power of the naming test described by ``strength``'s record ``s`` with its noise-free
    effect times ``scale``, against a floor estimated as in the trials
    (:func:`~vtestbed.researcher.floor_calibration.lr_power`); None for the detection test."""
    if "signal" not in s:
        return None
    return lr_power(scale * s["signal"], *s["power_args"])


def target_lambda(df: int, level: float, power: float = LIMIT_POWER) -> float:
    """The noncentrality at which a chi^2(df) test at ``level`` has power ``power`` (floor known)."""
    crit = chi2_dist.isf(level, df)
    return float(brentq(lambda lam: ncx2.sf(crit, df, lam) - power, 1e-6, 1e4))


def target_lambda_estimated_floor(s: dict, power: float) -> float:
    """The noise-free noncentrality at which the naming test of ``strength``'s record ``s`` has
    power ``power`` against the trials' estimated floor: the effect's pattern at ``s`` scaled by
    ``a`` until :func:`estimated_floor_power` is ``power``; then ``a^2 lambda``."""
    low, high = 1e-3, 1e3
    while estimated_floor_power(s, high) < power and high < 1e9:  # a pattern far below the noise
        low, high = high, high * 1e3
    a = brentq(lambda a: estimated_floor_power(s, a) - power, low, high, xtol=1e-4 * low)
    return float(a * a * s["lambda"])


def calibrate(
    name: str, ref_floor: NoiseFloor, max_evals: int, statics: str, power: float = LIMIT_POWER,
    known_floor: bool = False,
) -> dict:  # fmt: skip
    """f_lim for effect ``name`` (its naming test's power ``power`` in theory): a secant search on
    (log f, log lambda), lambda ~ f^2, towards the lambda at which the test has that power against
    the trials' estimated floor (``known_floor``: against the floor known exactly, the sizes used
    until 2026-11-26).

    f stays within the parameter's range; a world whose scans the researcher cannot reduce any
    more (the block sags out of the crop window) bounds f too: the search then halves the step
    in log f towards the last size that worked.
    """
    white = Whitener(ref_floor)
    f_range = max_factor(EFFECTS[name](), load_scenario(_discrepancy_worlds.SCENARIO))
    f_fail = math.inf
    s1 = strength(name, 1.0, white, statics)
    if known_floor or "signal" not in s1:  # the detection test (no candidate): as if the floor were known
        target = target_lambda(s1["df"], s1["level"], power)
    else:
        target = target_lambda_estimated_floor(s1, power)
    history, records = [(1.0, s1["lambda"])], {1.0: s1}
    failed = []

    def log_lam(lam):
        return math.log(max(lam, 1e-12))

    f = min(math.sqrt(target / max(s1["lambda"], 1e-12)), f_range)
    for _ in range(max_evals):
        try:
            records[f] = strength(name, f, white, statics)
            lam = records[f]["lambda"]
        except VtestbedError as exc:
            failed.append((f, str(exc).split(":")[0]))
            f_fail = min(f_fail, f)
            f = math.sqrt(max(h[0] for h in history if h[0] < f) * f)
            continue
        history.append((f, lam))
        if abs(log_lam(lam) - math.log(target)) < LIMIT_TOL:
            break
        if lam < target and f >= 0.999 * f_range:
            break
        (fa, la), (fb, lb) = history[-2], history[-1]
        slope = (log_lam(lb) - log_lam(la)) / (math.log(fb) - math.log(fa))
        slope = slope if 0.5 < slope < 4.0 else 2.0  # lambda ~ f^2 unless the data say otherwise
        f_new = math.exp(math.log(fb) + (math.log(target) - log_lam(lb)) / slope)
        if f_new >= f_fail:
            f_new = math.sqrt(fb * f_fail)
        f = min(f_new, f_range)
    tried = history[1:] or history
    best = min(tried, key=lambda h: abs(log_lam(h[1]) - math.log(target)))
    return {"name": name, "factor": best[0], "lambda_at_limit": best[1], "lambda_realistic": s1["lambda"],
            "target": target, "df": s1["df"], "level": s1["level"], "test": s1["test"], "label": s1["label"],
            "capped": bool(best[1] < target / math.exp(LIMIT_TOL)), "f_range": f_range,
            "f_fail": f_fail, "failed": failed, "history": history, "power": power,
            "floor": "known" if known_floor else "estimated",
            "power_realistic": estimated_floor_power(s1), "power_at_limit": estimated_floor_power(records[best[0]])}  # fmt: skip


def parse_effects(text: str, error) -> list[str]:
    """``--effects a,b`` as a list of effect names; ``error`` (argparse's ``parser.error``, which
    exits with code 2) on a name outside :data:`vtestbed.world.effects.EFFECTS`, listing them."""
    names = [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in EFFECTS]
    if unknown:
        error(f"unknown effect {unknown[0]!r}; valid: {', '.join(EFFECTS)}")
    return names


def parse_factors(items, names, flag: str, error) -> dict[str, float]:
    """Command-line sizes ``NAME=F`` as ``{name: F}``; ``error`` (argparse's ``parser.error``, which
    exits with code 2) on a name outside ``names`` (the run's effects) or an F that is not a number."""
    given = {}
    for item in items:
        name, _, value = item.partition("=")
        if name not in names:
            error(f"{flag} {item!r}: {name!r} is not among --effects ({', '.join(names)})")
        try:
            given[name] = float(value)
        except ValueError:
            error(f"{flag} {item!r}: F must be a number")
    return given


def given_size(name: str, factor: float, power: float) -> dict:
    """A near-limit size given on the command line (``--limit-factor``), for an effect that another
    test than its naming test detects first (the scanner's scale: the block's size); ``power`` is
    what the caller measured there, not a noncentrality's."""
    nan = float("nan")
    return {"name": name, "factor": factor, "given": True, "power": power, "power_at_limit": None,
            "power_realistic": None, "test": "given (--limit-factor)", "df": "-", "label": None,
            "lambda_realistic": nan, "lambda_at_limit": nan, "target": nan, "capped": False}  # fmt: skip


def candidate_overlap(ref_floor: NoiseFloor, statics: str) -> dict:
    """Per candidate: R^2 of its whitened columns on the stiffness columns (the 'absorbed' statistic),
    and per pair: the largest canonical correlation of their columns once the stiffness columns are
    projected out (1 = one can stand in for the other). Clean world, noise-free, reference floor."""
    white = Whitener(ref_floor)
    prepared, pool = prepared_world(None, 1.0, validation=False)
    ctx = model_context(noise_free(prepared), prepared, statics)
    c = fit_model(ctx, white, []).compliance
    ms = ctx.measurements
    aw = white(stack([m.jacobian for m in ms], [m.wrench for m in ms]))
    qa = np.linalg.qr(aw)[0]
    r2, bases = {}, {}
    for cand in pool:
        bw = white(cand.columns(ctx, c))
        perp = bw - qa @ (qa.T @ bw)
        r2[cand.label] = float(np.min(1 - np.sum(perp**2, axis=0) / np.sum(bw**2, axis=0)))
        u, s, _ = np.linalg.svd(perp, full_matrices=False)
        bases[cand.label] = u[:, s > s[0] * 1e-8]
    pairs = {}
    labels = list(bases)
    for i, a in enumerate(labels):
        for b in labels[i + 1 :]:
            pairs[(a, b)] = float(np.linalg.svd(bases[a].T @ bases[b], compute_uv=False)[0])
    return {"r2": r2, "pairs": pairs}
