"""Is the reported std honest on every design? Full-pipeline Monte Carlo per test set and estimator.

Test sets (issue 16, item 5): the paper's tests (``scenarios/kr60_paper.toml``, its first 12 and
all 20), the minimax designs of ``vtestbed poses design`` at 200 N and at the lab's tension limit
(588.6 N) with 12 and 20 tests (pool of ``--pool`` random poses, seed 0), and random tests (uniform
poses in the lab's block zone, hooks and rings by the campaign rule, 200 N; the first 12 and 20 of
one seeded stream). Each set is prepared once (MuJoCo equilibrium and ray cast,
:func:`vtestbed.campaigns.montecarlo.prepare`); each trial draws the scanner and F/T noise with its
seed and reduces the clouds (:func:`~vtestbed.campaigns.montecarlo.measure_trial`). The measured
Jacobians, wrenches and displacements of every trial are cached (``--cache``), and every estimator
identifies the same trials.

Per set, joint and estimator it prints the Monte Carlo std of ``k/k_true - 1``, the mean reported
std and its variation between trials (``rep CV``, std / mean), the z-score ``(k - k_true)/k_std``
std and mean, the Cramer-Rao bound (:mod:`vtestbed.design.crlb`) and the efficiency CRLB^2 / MSE.
Honest: z-score std within [0.8, 1.25] (docs/uncertainty.md).

``gls_floor`` weights with the repeat-scan noise floor of the tests it uses: every trial also
draws ``--repeats`` repeat scans per test (:func:`~vtestbed.world.repeats.repeat_rng`, as
``simulate`` writes them) and caches their fitted frames.

Run: .venv/bin/python benchmarks/bench_design_uncertainty.py [--trials 40] [--cache DIR] [--workers 2]
(one worker; about 4 s per trial of the six scenarios on this machine, plus about a minute for the
random set's feasibility checks; a second run with the same --cache and --trials only identifies, 40 s).
"""

from __future__ import annotations

import argparse
import multiprocessing
import subprocess
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

import vtestbed as vt
from vtestbed.campaigns import posesets
from vtestbed.campaigns.montecarlo import measure_trial, prepare, repeat_frames
from vtestbed.campaigns.spec import pose_set_defaults
from vtestbed.design import crlb
from vtestbed.design import optimal as design
from vtestbed.researcher.identify import identify
from vtestbed.researcher.kinematics import ArmKinematics
from vtestbed.researcher.measure import gls_floor_covariance, stacked
from vtestbed.researcher.noise_floor import noise_floor_from_frames

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "scenarios" / "kr60_paper.toml"
ESTIMATORS = ("fgls", "fgls_pooled", "fgls6", "gls_floor")
REPEATS = 3  # repeat scans per test for gls_floor's floor
DESIGNS = {"minimax_200N": 200.0, "minimax_limit": None}  # None: the lab's limit (--tension default)
HONEST = (0.8, 1.25)


def design_scenario(out: Path, tests: int, tension: float | None, pool: int) -> Path:
    """``vtestbed poses design`` (minimax, truth prior as in docs/poses.md), written to ``out``."""
    path = out / "design_scenario.toml"
    if not path.exists():
        cmd = [sys.executable, "-m", "vtestbed", "poses", "design", "--stiffness-prior", "paper_table5",
               "--tests", str(tests), "--n", str(pool), "--no-bound", "--out", str(out)]  # fmt: skip
        if tension is not None:
            cmd += ["--tension", str(tension)]
        subprocess.run(cmd, check=True, capture_output=True)
    return path


def random_scenario(base, n: int, seed: int):
    """``n`` random tests at the base scenario's lab (the campaigns' ``random`` pose set rule)."""
    opts = pose_set_defaults(base.lab)
    checker = posesets.FeasibilityChecker(base)
    kin = ArmKinematics(base.robot, base.lab.block_in_flange)
    stream = posesets.random_poses(base.robot, opts, np.random.default_rng(seed))
    return posesets.nested_plan("random", stream, n, checker, kin, opts.tension_N).scenario(base)


def test_sets(cache: Path, pool: int) -> dict:
    """name -> (scenario, test counts): each scenario's first n tests for every n."""
    base = vt.load_scenario(PAPER)
    sets = {"paper": (base, (12, 20)), "random": (random_scenario(base, 20, 7), (12, 20))}
    for name, tension in DESIGNS.items():
        for n in (12, 20):
            path = design_scenario(cache / f"{name}_{n}", n, tension, pool)
            sets[f"{name}_{n}"] = (vt.load_scenario(path), (n,))
    return sets


def measured_path(name: str, trials: int, cache: Path) -> Path:
    """Where :func:`measure` keeps a set's trials."""
    return cache / f"{name}_trials{trials}_r{REPEATS}.npz"


def _fewer_trials(name: str, trials: int, cache: Path) -> dict:
    """The largest cached run of the set with fewer than ``trials`` trials (empty: none). Trial i
    always has seed 16_000 + i, so a longer run starts with the shorter one's trials."""
    runs = {}
    for path in cache.glob(f"{name}_trials*_r{REPEATS}.npz"):
        count = path.name[len(name) + len("_trials") :].split("_r")[0]
        if count.isdigit() and int(count) < trials:
            runs[int(count)] = path
    return dict(np.load(runs[max(runs)])) if runs else {}


def measure(name: str, scenario, trials: int, cache: Path) -> dict:
    """Cached (trials, T, ...) Jacobians, wrenches, displacements, the fitted frames of each
    test's unloaded scan and its REPEATS repeats (trials, T, REPEATS + 1, 4, 4), and the truth.

    A cached shorter run of the set is extended (its trials are the first ones of the longer run).
    """
    path = measured_path(name, trials, cache)
    if path.exists():
        return dict(np.load(path))
    t0 = time.perf_counter()
    earlier = _fewer_trials(name, trials, cache)
    done = len(earlier.get("jacobians", ()))
    prepared = prepare(scenario)
    noise = scenario.scanner.noise_model
    jac, wr, disp, frames = [], [], [], []
    for i in range(done, trials):
        ms = measure_trial(prepared, 16_000 + i)
        j, w, d = stacked(ms)
        jac.append(j), wr.append(w), disp.append(d)
        per_test = repeat_frames(prepared, 16_000 + i, prepared.identification_tests(), ms, noise, REPEATS)
        frames.append(list(per_test.values()))
    new = dict(jacobians=np.array(jac), wrenches=np.array(wr), displacements=np.array(disp),
               repeat_frames=np.array(frames))  # fmt: skip
    out = {key: np.concatenate([earlier[key], v]) if done else v for key, v in new.items()}
    out["k_true"] = prepared.stiffness_true
    if done and not np.array_equal(earlier["k_true"], out["k_true"]):
        raise SystemExit(f"{name}: the cached {done} trials have another truth; remove them from {cache}")
    np.savez(path, **out)
    print(
        f"  {name}: {len(prepared.tests)} tests x {trials - done} trials in {time.perf_counter() - t0:.0f} s"
        + (f" (the first {done} from the cache)" if done else ""),
        flush=True,
    )
    return out


def scenario_a(scenario, n: int | None = None) -> np.ndarray:
    """(n, 6, n_joints) nominal ``A`` of the scenario's first ``n`` tests (all: None), no checks."""
    sc, load = scenario, scenario.load
    return np.array([design.candidate_tests(sc.robot, q[None], [h], [r], t, sc.lab, check_sensor=False,
                                            outward=False, clearance=False)[0].a
                     for q, h, r, t in list(zip(sc.poses, load.hooks, load.anchors, load.tensions))[:n]])  # fmt: skip


def bound(scenario, n: int, k_true: np.ndarray) -> np.ndarray:
    """(n_joints,) relative CRLB std(k)/k of the scenario's first n tests (bench_crlb's chain)."""
    sc = scenario
    a = scenario_a(sc, n)
    spacing = sc.scanner.spacing or crlb.DEFAULT_SPACING_M
    cov = crlb.pose_covariances(sc.robot, sc.poses[:n], sc.scanner.noise_model, sc.lab, sc.scanner.distance,
                                spacing_m=spacing)  # fmt: skip
    return crlb.stiffness_bound(a, cov, k_true).relative_std


def identify_trials(data: dict, n: int, method: str) -> tuple[np.ndarray, np.ndarray]:
    """(trials, n_joints) estimates and reported stds [N*m/rad] from each trial's first n tests
    (``gls_floor``: weighted with the noise floor of those n tests' repeat scans, as
    :func:`~vtestbed.researcher.measure.gls_floor_covariance` gives it to the tool)."""
    ks, stds = [], []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for j, w, d, fr in zip(
            data["jacobians"], data["wrenches"], data["displacements"], data["repeat_frames"]
        ):
            cov = None
            if method == "gls_floor":
                floor = noise_floor_from_frames({f"T{t + 1:03d}": list(fr[t]) for t in range(n)})
                cov = gls_floor_covariance(floor)
            res = identify(j[:n], w[:n], d[:n], method=method, displacement_cov=cov)
            ks.append(res.stiffness), stds.append(res.stiffness_std)
    return np.array(ks), np.array(stds)


def joint_check(name: str, scenario, data: dict, a: np.ndarray, err: np.ndarray) -> str:
    """Per joint [%], a set's Monte Carlo std (of ``err`` (trials, joints), the relative errors of
    its identifications from all its tests) against its predictions: the design's (``SIGMA_P`` /
    ``SIGMA_R``) and the Cramer-Rao bound (the scan's full covariance, drift correlation included).
    Then the scan noise itself: the displacements' covariance over the trials (B's axes, as the
    researcher measures them), pooled over the tests and whitened by the bound's model, whose
    eigenvalues are 1 where the model is right."""
    n, k = len(a), data["k_true"]
    rows = {"MC std": err.std(axis=0, ddof=1), "design": design.evaluate(a, k).relative_std,
            "CRLB": bound(scenario, n, k)}  # fmt: skip
    spacing = scenario.scanner.spacing or crlb.DEFAULT_SPACING_M
    scan = crlb.nominal_scan(scenario.lab.block.edge, scenario.scanner.distance, spacing_m=spacing)
    model = 2.0 * crlb.frame_covariance(scan, scenario.scanner.noise_model)  # a displacement, B's axes
    e = data["displacements"] - data["displacements"].mean(axis=0)
    pooled = np.einsum("stk,stl->kl", e, e) / (e.shape[1] * (e.shape[0] - 1))
    whiten = np.linalg.cholesky(np.linalg.inv(model))
    text = [f"  {name} ({n} tests, {len(err)} trials), per joint [%]:"]
    text += [
        f"    {label:>7s} " + " ".join(f"{100 * v:6.3f}" for v in values) for label, values in rows.items()
    ]
    text.append("    scan noise, pooled covariance whitened by the model's: eigenvalues "
                + " ".join(f"{v:.2f}" for v in np.linalg.eigvalsh(whiten.T @ pooled @ whiten)))  # fmt: skip
    return "\n".join(text)


def evaluate(data: dict, n: int, method: str) -> dict:
    """Per joint: MC std, mean reported std and its variation between trials (std / mean),
    RMS error (relative), z-score std and mean."""
    k_true = data["k_true"]
    ks, stds = identify_trials(data, n, method)
    err = ks / k_true - 1
    z = (ks - k_true) / stds
    return {"mc": err.std(axis=0, ddof=1), "reported": np.mean(stds, axis=0) / k_true,
            "rms": np.sqrt(np.mean(err**2, axis=0)), "z_std": z.std(axis=0, ddof=1), "z_mean": z.mean(axis=0),
            "cv": np.std(stds, axis=0) / np.mean(stds, axis=0)}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--trials", type=int, default=40, help="Monte Carlo trials per set (default %(default)s)"
    )
    parser.add_argument(
        "--pool", type=int, default=400, help="random poses of the design pool (default %(default)s)"
    )
    parser.add_argument("--cache", default=str(ROOT / "runs" / "bench_design_uncertainty"),
                        help="directory for the designs and the measured trials (default %(default)s)")  # fmt: skip
    parser.add_argument("--methods", default=",".join(ESTIMATORS), help="estimators (default %(default)s)")
    parser.add_argument("--workers", type=int, default=1, help="processes measuring the sets")
    args = parser.parse_args()
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    methods = args.methods.split(",")
    sets = test_sets(cache, args.pool)
    if args.workers > 1:  # measure (and cache) the sets in parallel; the report below reads the cache
        with ProcessPoolExecutor(args.workers, mp_context=multiprocessing.get_context("spawn")) as pool:
            list(pool.map(measure, list(sets), [s for s, _ in sets.values()], [args.trials] * len(sets),
                          [cache] * len(sets)))  # fmt: skip
    se = 1 / np.sqrt(2 * (args.trials - 1))
    print(f"{args.trials} trials per set; a z-score std from them is uncertain by about {se * 100:.0f} %; "
          f"honest: z std in [{HONEST[0]}, {HONEST[1]}]")  # fmt: skip
    summary = []
    for name, (scenario, counts) in sets.items():
        data = measure(name, scenario, args.trials, cache)
        for n in counts:
            lb = bound(scenario, n, data["k_true"])
            print(f"\n{name}, {n} tests; relative to k_true [%]; CRLB {np.round(lb * 100, 3).tolist()}")
            print(f"{'method':12s}{'joint':>6s}{'MC std':>9s}{'reported':>9s}{'rep/MC':>8s}{'rep CV':>7s}{'z std':>7s}"
                  f"{'z mean':>8s}{'CRLB':>8s}{'eff.':>6s}")  # fmt: skip
            for method in methods:
                r = evaluate(data, n, method)
                for j in range(len(lb)):
                    print(f"{method:12s}{j + 1:6d}{r['mc'][j] * 100:9.3f}{r['reported'][j] * 100:9.3f}"
                          f"{r['reported'][j] / r['mc'][j]:8.2f}{r['cv'][j]:7.2f}{r['z_std'][j]:7.2f}{r['z_mean'][j]:8.2f}"
                          f"{lb[j] * 100:8.3f}{lb[j] ** 2 / r['rms'][j] ** 2:6.2f}")  # fmt: skip
                honest = bool(np.all((r["z_std"] >= HONEST[0]) & (r["z_std"] <= HONEST[1])))
                summary.append((f"{name}:{n}" if name.startswith(("paper", "random")) else name, method,
                                r["z_std"], honest, np.median(lb**2 / r["rms"] ** 2)))  # fmt: skip
    print("\nsummary: z-score std per joint (honest = all in range), median efficiency CRLB^2/MSE")
    for label, method, z, honest, eff in summary:
        print(
            f"{label:20s}{method:12s}{np.round(z, 2)}  {'honest' if honest else 'NOT honest':10s} eff {eff:.2f}"
        )


if __name__ == "__main__":
    main()
