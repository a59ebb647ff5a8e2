"""The Cramer-Rao bound of the paper scenario's stiffnesses against a full-pipeline Monte Carlo.

A small campaign on ``scenarios/kr60_paper.toml`` (its 20 tests, the VTOP 200B noise model,
FGLS, one worker): per joint the Monte Carlo std and RMS error, the mean reported std, the design
module's prediction (SIGMA_P, SIGMA_R), the CRLB from the scanner's point-noise model
(:mod:`vtestbed.design.crlb`) and the efficiency CRLB^2 / MSE.

``--method gls_floor`` weights with the repeat-scan noise floor instead (each trial draws
``--repeats`` repeat scans per test, 3 by default); the "z std" column is the std of
``(k - k_true) / k_std`` over the trials (1 for an honest reported std).

Run: .venv/bin/python benchmarks/bench_crlb.py [--trials 40] [--method fgls|gls_floor|ols] [--repeats 3]
"""

from __future__ import annotations

import argparse
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np

import vtestbed as vt
from vtestbed.campaigns.spec import parse_campaign
from vtestbed.design import crlb
from vtestbed.design import optimal as design

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=40, help="Monte Carlo trials (default %(default)s)")
    parser.add_argument("--scenario", default=str(ROOT / "scenarios/kr60_paper.toml"),
                        help="scenario file, e.g. a design_scenario.toml of 'vtestbed poses design'")  # fmt: skip
    parser.add_argument("--method", default="fgls", choices=("fgls", "ols", "gls_floor"))
    parser.add_argument("--repeats", type=int, default=3, help="repeat scans per test for gls_floor")
    args = parser.parse_args()
    base = vt.load_scenario(args.scenario)
    data = tomllib.loads(Path(args.scenario).read_text())
    data["campaign"] = {"seed": 16, "trials": args.trials, "paired": True,
                        "axes": {"pose_set": ["scenario"], "n_tests": [base.n_tests], "method": [args.method]}}  # fmt: skip
    if args.method == "gls_floor":
        data.setdefault("scanner", {})["repeats"] = args.repeats
    with tempfile.TemporaryDirectory() as tmp:
        campaign = parse_campaign(data, Path(args.scenario))
        t0 = time.perf_counter()
        trials = vt.sweep(campaign, Path(tmp) / "out", workers=1)
        sweep_s = time.perf_counter() - t0
    sc = campaign.scenario
    trials = trials[trials["status"] == "ok"]
    names = sc.robot.joint_names
    k_true = np.array([trials[f"k_true_{n}"].iloc[0] for n in names])
    k = np.array([trials[f"k_{n}"].to_numpy() for n in names])  # (6, trials)
    k_std = np.array([trials[f"k_std_{n}"].to_numpy() for n in names])

    t0 = time.perf_counter()
    load = sc.load
    tests = [design.candidate_tests(sc.robot, q[None], [h], [r], t, sc.lab, check_sensor=False, outward=False,
                                    clearance=False)[0]
             for q, h, r, t in zip(sc.poses, load.hooks, load.anchors, load.tensions)]  # fmt: skip
    a = np.array([t.a for t in tests])
    spacing = sc.scanner.spacing or crlb.DEFAULT_SPACING_M
    cov = crlb.pose_covariances(sc.robot, sc.poses, sc.scanner.noise_model, sc.lab, sc.scanner.distance,
                                spacing_m=spacing)  # fmt: skip
    bound = crlb.stiffness_bound(a, cov, k_true)
    crlb_s = time.perf_counter() - t0
    predicted = design.evaluate(a, k_true)  # the design's diagonal SIGMA_P, SIGMA_R
    # the best FGLS can do: weights = the true per-component variances (diagonal), true covariance
    # (drift couples translation and rotation) in the sandwich (A^T W A)^-1 A^T W Sigma W A (A^T W A)^-1
    w = np.array([np.diag(1 / np.diagonal(c)) for c in cov])
    bread = np.linalg.inv(np.einsum("tki,tkl,tlj->ij", a, w, a))
    meat = np.einsum("tki,tkl,tlm,tmn,tnj->ij", a, w, cov, w, a)
    diag_wls = np.sqrt(np.diag(bread @ meat @ bread)) * k_true

    scan = crlb.nominal_scan(sc.lab.block.edge, sc.scanner.distance, spacing_m=spacing)
    frame = np.sqrt(np.diag(crlb.frame_covariance(scan, sc.scanner.noise_model)))
    points = np.sqrt(np.diag(np.linalg.inv(crlb.frame_information(scan, sc.scanner.noise_model))))
    disp = bound.displacement_std
    print(f"scan: {len(scan.points)} points on the block ({np.bincount(scan.face).tolist()} per face)")
    print(f"per frame, point noise only [um | urad]: {np.round(points[:3] * 1e6, 3).tolist()} | "
          f"{np.round(points[3:] * 1e6, 2).tolist()}")  # fmt: skip
    print(f"per frame, with the drift [um | urad]: {np.round(frame[:3] * 1e6, 2).tolist()} | "
          f"{np.round(frame[3:] * 1e6, 2).tolist()}")  # fmt: skip
    print(f"per displacement, RMS over tests and axes: {np.sqrt(np.mean(disp[:, :3] ** 2)) * 1e6:.2f} um, "
          f"{np.sqrt(np.mean(disp[:, 3:] ** 2)) * 1e6:.2f} urad  (design's SIGMA_P, SIGMA_R: "
          f"{design.SIGMA_P * 1e6:.1f} um, {design.SIGMA_R * 1e6:.1f} urad)")  # fmt: skip
    print(f"\n{len(trials)} trials of {sc.name} ({sc.n_tests} tests, {args.method}); "
          "relative to k_true [%]")  # fmt: skip
    head = f"{'joint':8s}{'MC std':>9s}{'RMS err':>9s}{'reported':>9s}{'design':>9s}{'diagWLS':>9s}{'CRLB':>9s}{'eff.':>7s}{'MC/CRLB':>9s}{'z std':>7s}"
    print(head)
    for j, name in enumerate(names):
        err = k[j] / k_true[j] - 1
        mc, rms = err.std(ddof=1), np.sqrt(np.mean(err**2))
        rep = np.mean(k_std[j]) / k_true[j]
        lb = bound.relative_std[j]
        print(f"{name:8s}{mc * 100:9.3f}{rms * 100:9.3f}{rep * 100:9.3f}{predicted.relative_std[j] * 100:9.3f}"
              f"{diag_wls[j] * 100:9.3f}"
              f"{lb * 100:9.3f}{lb**2 / rms**2:7.2f}{mc / lb:9.2f}"
              f"{np.std((k[j] - k_true[j]) / k_std[j], ddof=1):7.2f}")  # fmt: skip
    se = 1 / np.sqrt(2 * (len(trials) - 1))
    print(
        f"(an MC std from {len(trials)} trials is uncertain by about {se * 100:.0f} %; efficiency by twice that)"
    )
    print(f"\ntimes: sweep {sweep_s:.1f} s ({sweep_s / max(len(trials), 1):.2f} s/trial, one worker); "
          f"CRLB of {len(tests)} tests {crlb_s * 1e3:.0f} ms")  # fmt: skip


if __name__ == "__main__":
    main()
