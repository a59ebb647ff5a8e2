"""The worlds and trials of ``bench_discrepancy.py``: effects at a size, one dataset's noise
through the researcher's workflow.

A world is the scenario (``--scenario``, default ``scenarios/kr60_paper.toml``) with one hidden
effect (or ``"a+b"``: two) at ``f`` times its realistic size; its physics is prepared once per
worker process. A trial draws one dataset's noise from its seed exactly as ``vtestbed simulate``
would and runs the researcher's reduction and ``name_effects`` on it (``bench_discrepancy.py``'s
docstring gives the chain). The settings ``main`` takes from the command line (``SCENARIO``,
``RANK``, ``REPEATS``, ``LOADED_REPEATS``) are module attributes read at call time, and environment variables
for the spawned workers, which re-import this module. Units: SI.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"  # before numpy: also in every spawned worker, which imports this module

import dataclasses  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from vtestbed.campaigns.montecarlo import measure_trial, prepare, repeat_frames  # noqa: E402
from vtestbed.researcher.candidates import BLOCK_OFFSET_LABELS, ModelContext, candidates  # noqa: E402
from vtestbed.researcher.diagnose import (  # noqa: E402
    DEFAULT_RANK,
    validation_gap,
)
from vtestbed.researcher.model_file import SPLIT_TERMS, baseline_statics  # noqa: E402
from vtestbed.researcher.naming_run import run_naming  # noqa: E402
from vtestbed.researcher.noise_floor import NoiseFloor, noise_floor_from_frames  # noqa: E402
from vtestbed.researcher.reading_noise import with_reading_noise  # noqa: E402
from vtestbed.researcher.scale_term import named_labels  # noqa: E402
from vtestbed.researcher.scan_mean import against_scan_mean  # noqa: E402

# the paper scenario keeps its 7 unclear tests (docs/clearance.md): known, not repeated per world
warnings.filterwarnings("ignore", message=r".* is not physically possible")
from vtestbed.scenario import load_scenario  # noqa: E402
from vtestbed.world.effects import EFFECTS  # noqa: E402
from vtestbed.world.sensors import ForceTorqueSensor  # noqa: E402
from vtestbed.world.truth import load_truth  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
# --scenario sets it for the spawned workers too (they re-import this module and read the variable)
SCENARIO = Path(os.environ.get("VTESTBED_BENCH_SCENARIO", ROOT / "scenarios" / "kr60_paper.toml"))
ALPHA = 0.01
RANK = os.environ.get("VTESTBED_BENCH_RANK", DEFAULT_RANK)  # --rank, for the spawned workers too
# --repeats: scans of the unloaded block per test beyond its own ([scanner] repeats; 3 as
# scenarios/kr60_hidden_link.toml), an environment variable for the spawned workers as below
REPEATS = int(os.environ.get("VTESTBED_BENCH_REPEATS", "3"))
# --loaded-repeats: scans of the loaded block per test beyond its own (0: the paper's one scan;
# an environment variable so that the spawned workers see it too)
LOADED_REPEATS = int(os.environ.get("VTESTBED_BENCH_LOADED_REPEATS", "0"))


def set_loaded_repeats(repeats: int) -> None:
    """``LOADED_REPEATS`` here and in the environment, which the spawned workers read on import."""
    global LOADED_REPEATS
    LOADED_REPEATS = repeats
    os.environ["VTESTBED_BENCH_LOADED_REPEATS"] = str(repeats)


def set_repeats(repeats: int) -> None:
    """``REPEATS`` here and in the environment, which the spawned workers read on import."""
    global REPEATS
    REPEATS = repeats
    os.environ["VTESTBED_BENCH_REPEATS"] = str(repeats)


def set_scenario(path: Path) -> None:
    """``SCENARIO`` here and in the environment, which the spawned workers read on import; the
    prepared world of another scenario is dropped (its key names the effect and size only)."""
    global SCENARIO
    SCENARIO = Path(path).resolve()
    os.environ["VTESTBED_BENCH_SCENARIO"] = str(SCENARIO)
    _PREPARED.clear()


SEED0 = 2023  # trial k uses scenario seed SEED0 + k
# The reference floor (only for choosing f_lim): 200 repeats of the 25 tests, 5000 samples, so its
# variances err by about 2 %. With 10 repeats (until 2026-11-29) they erred by about 9 % (the floor of
# seed 977 read x and rx 4-5 % short in std), and a near-limit size by as much in lambda.
REF_SEED, REF_REPEATS = 977, 200
CHUNK = 5  # seeds per task

# How an effect's size scales with the factor f: +1 fields are multiplied by f, -1 fields (a
# stiffness standing for a compliance) divided by f.
SIZE_FIELDS = {
    "link_compliance": {"stiffness_Nm_per_rad": -1},
    "joint_coupling": {"stiffness_Nm_per_rad": +1},
    "nonlinear_joint": {"k3_Nm_per_rad3": +1},
    "gravity_compensator": {"spring_rate_N_per_m": +1},
    "base_compliance": {"stiffness_Nm_per_rad": -1},
    "ft_misalignment": {"roll_pitch_yaw_deg": +1},
    "ft_bias_drift": {"drift_N_Nm": +1},
    "geometric_error": {"da_mm": +1, "dd_mm": +1, "dalpha_deg": +1, "dtheta_deg": +1},
    "block_offset": {"translation_mm": +1, "rotation_deg": +1},
    "scanner_scale": {"scale_ppm": +1},
    "load_creep": {"rate_percent": +1},
}
# load_creep moves only repeat scans of the loaded block, and no candidate names it: the creep check
# (researcher/loaded_scatter.py) looks for it, tests/test_load_creep.py measures that; not a default world
DEFAULT_EFFECTS = tuple(n for n in EFFECTS if n != "load_creep")


# ---------------------------------------------------------------------------- effects and worlds
def _scale_value(value, sign: int, f: float):
    if isinstance(value, tuple):
        return tuple(_scale_value(v, sign, f) for v in value)
    return value * f if sign > 0 else value / f


def scaled(effect, f: float):
    """The effect at ``f`` times its size (a compliance's stiffness divided by f)."""
    if f == 1.0:
        return effect
    fields = SIZE_FIELDS[effect.name]
    return dataclasses.replace(
        effect, **{k: _scale_value(getattr(effect, k), s, f) for k, s in fields.items()}
    )


def max_factor(effect, scenario) -> float:
    """The largest f the effect's parameter ranges (and, for a coupling, the world) accept."""
    params = {p.name: p for p in effect.PARAMS}
    f_max = 1e6
    for name, sign in SIZE_FIELDS[effect.name].items():
        values = np.atleast_1d(np.asarray(getattr(effect, name), dtype=float))
        p = params[name]
        for v in values[np.isfinite(values) & (values != 0)]:
            if sign > 0:
                f_max = min(f_max, (p.high if v > 0 else p.low) / v)
            else:
                f_max = min(f_max, v / p.low)
    if effect.name == "joint_coupling":  # |k_ij| < sqrt(k_i k_j): the world's own limit
        k = load_truth(scenario.robot_name).stiffness_true
        i, j = effect.joints[0] - 1, effect.joints[1] - 1
        f_max = min(f_max, 0.9 * np.sqrt(k[i] * k[j]) / abs(effect.stiffness_Nm_per_rad))
    return float(f_max)


def expected_label(effect) -> str:
    """The candidate label that stands for ``effect`` (its family and instance)."""
    if effect.name == "link_compliance":
        return f"link_compliance(link {effect.link})"
    if effect.name == "joint_coupling":
        return f"joint_coupling({min(effect.joints)},{max(effect.joints)})"
    if effect.name == "nonlinear_joint":
        return f"nonlinear_joint({effect.joint})"
    if effect.name == "block_offset":  # its rotation carries 99 % of what the scans see (candidates.py)
        return BLOCK_OFFSET_LABELS["rotation"]
    return effect.name


def true_labels(effect) -> frozenset[str]:
    """Every candidate label that describes ``effect`` as hidden: its :func:`expected_label`, or
    for a term split into parts every part (``model_file.SPLIT_TERMS``: the block offset's world
    turns and shifts the block, so a name of either part is right; the search names both where
    both are significant)."""
    return frozenset(SPLIT_TERMS.get(effect.name, (expected_label(effect),)))


def world_key(name: str | None, size: str) -> str:
    return "clean" if name is None else f"{name} @ {size}"


def world_scenario(base, name: str | None, factor: float):
    """``base`` with the effect ``name`` hidden at ``factor`` times its size; ``"a+b"`` hides
    both (benchmarks/bench_two_effects.py)."""
    if name is None:
        return base
    return dataclasses.replace(base, effects=tuple(scaled(EFFECTS[n](), factor) for n in name.split("+")))


_PREPARED: dict = {}  # one prepared world per worker process (tasks of a world come in a row)


def prepared_world(name: str | None, factor: float, validation: bool = True):
    key = (name, factor, validation)
    if key not in _PREPARED:
        _PREPARED.clear()
        scenario = world_scenario(load_scenario(SCENARIO), name, factor)
        prepared = prepare(scenario, include_validation=validation)
        _PREPARED[key] = (prepared, candidates(prepared.kinematics))
    return _PREPARED[key]


# ---------------------------------------------------------------------------- one trial
def model_context(measurements, prepared, statics: str) -> ModelContext:
    """As ``discrepancy.diagnose`` builds it: ``statics="exact"`` (its default) takes the clean
    world's exact statics (:class:`~vtestbed.researcher.statics.ExactStatics`) as the baseline."""
    exact = baseline_statics(statics, prepared.kinematics, prepared.setup)
    return ModelContext(measurements, prepared.setup, prepared.kinematics, exact)


def trial(prepared, pool, seed: int, statics: str) -> dict:
    """One dataset's worth of noise (seed ``seed``) through the researcher's workflow."""
    scenario = prepared.scenario
    t0 = time.perf_counter()
    # test_rng + draw_readings per test; with the block's edges for the scale check, as diagnose
    ms = measure_trial(prepared, seed, list(prepared.tests), edges=True)
    t1 = time.perf_counter()
    noise = scenario.scanner.noise_model
    frames = repeat_frames(prepared, seed, list(prepared.tests), ms, noise, REPEATS)
    loaded = (
        repeat_frames(prepared, seed, list(prepared.tests), ms, noise, LOADED_REPEATS, "loaded")
        if LOADED_REPEATS
        else None
    )
    # as load_with_floor: every displacement against its test's mean unloaded scan (to its mean
    # loaded scan with --loaded-repeats, unless the creep check fails at ALPHA), the floor for it
    ms, floor = against_scan_mean(ms, frames, noise_floor_from_frames(frames), loaded, ALPHA)
    floor = with_reading_noise(floor, ms, prepared.setup)  # the F/T readings' noise, as load_with_floor
    t2 = time.perf_counter()
    # as diagnose: detect, settle the scale on the block, name (the same core, naming_run)
    exact = baseline_statics(statics, prepared.kinematics, prepared.setup)
    run = run_naming(ms, prepared.setup, prepared.kinematics, exact, floor, pool, ALPHA, RANK)
    ctx, ctx_val, white, base, check, term = run.ctx, run.ctx_val, run.white, run.base, run.scale, run.term
    fixed_val, chosen, steps, final = run.fixed_val, run.chosen, run.steps, run.final
    before = validation_gap(ctx_val, white, base, [])["ratio_to_floor"]
    gap_after = validation_gap(fixed_val, white, final, chosen)
    after = gap_after["ratio_to_floor"]
    t3 = time.perf_counter()
    return {
        "seed": seed,
        "named": named_labels([c.label for c in chosen], term),
        "names": named_labels([c.name for c in chosen], term),
        "scale_check": check and check.to_dict(),
        "scale_term": term and term.to_dict(),
        "dropped": [d["label"] for s in steps for d in s.dropped],  # named, then stood in for later terms
        "chi2": base.chi2,
        "dof": base.dof,
        "p_detect": base.p_value,
        "round1": [
            {k: r[k] for k in ("label", "name", "lr", "df", "p_value", "bic", "press", "significant")}
            for r in steps[0].tests
        ],  # fmt: skip
        # the later rounds' tests too: what a second effect's likelihood ratio was beyond the first
        "later_rounds": [
            {
                "base": list(s.base_terms),
                "level": s.level,
                "tests": [
                    {k: r[k] for k in ("label", "lr", "df", "p_value", "significant")} for r in s.tests
                ],
            }
            for s in steps[1:]
        ],  # fmt: skip
        "val_before": before,
        "val_after": after,
        "val_expected_after": gap_after["expected_ratio"],  # a correct model with the named terms
        "runner_up": steps[0].runner_up,
        "delta": steps[0].delta,
        "delta_bic": steps[0].delta_bic,
        "fit_before": float(np.sqrt(base.chi2 / (6 * ctx.n_tests))),
        "fit_after": float(np.sqrt(final.chi2 / (6 * ctx.n_tests))),
        "floor_std": floor.component_std.tolist(),
        "loaded_left_out": bool(floor.loaded_scatter is not None and floor.loaded_scatter.left_out),
        "time": {"measure": t1 - t0, "floor": t2 - t1, "diagnose": t3 - t2, "total": t3 - t0},
    }


def run_chunk(name: str | None, factor: float, seeds: list[int], statics: str) -> tuple[list[dict], float]:
    t0 = time.perf_counter()
    prepared, pool = prepared_world(name, factor)
    t_prep = time.perf_counter() - t0
    out = []
    for seed in seeds:
        try:
            out.append(trial(prepared, pool, seed, statics))
        except Exception as exc:  # one broken trial must not lose the run: recorded, counted, printed
            out.append(
                {"seed": seed, "error": f"{type(exc).__name__}: {exc}", "trace": traceback.format_exc()}
            )
    return out, t_prep


# ---------------------------------------------------------------------------- noise-free, and the reference floor
def noise_free(prepared, tests=None):
    """``tests`` (default: the identification tests) reduced from a perfect scanner and a
    noise-free F/T sensor."""
    scenario = prepared.scenario
    sensor = ForceTorqueSensor(scenario.lab.sensor, (0.0,) * 6, scenario.force_sensor.bias)
    tests = prepared.identification_tests() if tests is None else tests
    return measure_trial(prepared, 0, tests, noise=None, sensor=sensor)


def reference_floor(repeats: int) -> NoiseFloor:
    """The clean world's floor from ``repeats`` repeats of every test (seed REF_SEED), with its
    sample count (the whitener divides out the chi^2 inflation of an estimated floor), for the
    trials' displacements (against the mean of ``REPEATS + 1`` unloaded scans, to the mean of
    ``LOADED_REPEATS + 1`` loaded ones), the F/T readings' noise added as the trials add it."""
    prepared, _ = prepared_world(None, 1.0)  # the clean world: no effects in the repeats
    ms = measure_trial(prepared, REF_SEED, list(prepared.tests))
    noise = prepared.scenario.scanner.noise_model
    floor = noise_floor_from_frames(
        repeat_frames(prepared, REF_SEED, list(prepared.tests), ms, noise, repeats)
    ).for_scan_mean(REPEATS + 1, LOADED_REPEATS + 1)  # the trials' displacements, both ends
    return with_reading_noise(floor, ms, prepared.setup)
