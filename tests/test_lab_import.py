"""Raw lab files into a dataset (vtestbed.lab_import, vtestbed.ft_stream, ``vtestbed dataset import``).

The reference: a dataset simulated by the truth world. From it the tests write what a lab
records (500 Hz F/T streams around each recorded reading, with a transient before the static
window and seeded noise; clouds as PCD and XYZ files in mm), import them, and identify both
datasets. Stream statistics are checked against the known mean and std of the synthetic noise.
"""

from __future__ import annotations

import csv
import json
import shutil
import subprocess
import sys

import numpy as np
import pytest
from conftest import paper_scenario_data
from test_architecture import forbidden_reach

from vtestbed import ft_stream
from vtestbed.cli.main import main
from vtestbed.dataset import read_tests
from vtestbed.dataset_repeats import read_repeats
from vtestbed.experiment import identify_dataset, simulate
from vtestbed.lab_import import ImportOptions, import_dataset, read_cloud
from vtestbed.ply import read_ply
from vtestbed.scenario import parse_scenario
from vtestbed.transforms import rotation_vector
from vtestbed.world.sensors import DEFAULT_NOISE_STD

FS_HZ = 500.0
DURATION_S = 4.0
TRANSIENT_END_S = 1.0  # the synthetic transient is exactly zero from here on
WINDOW_S = (2.0001, 3.5001)  # between samples: which samples are in it is unambiguous
SIGMA = np.array(DEFAULT_NOISE_STD)  # N, N*m: the ATI resolution the world uses
TRANSIENT = np.array([15.0, -10.0, 25.0, 0.8, -0.5, 0.3])  # N, N*m amplitude of the ringing


def stream(mean: np.ndarray, rng: np.random.Generator, centred_in=None, sigma=SIGMA, duration=DURATION_S):
    """(time (n,) [s], wrench (n, 6) [N, N*m]): ``mean`` + a decaying ringing before
    TRANSIENT_END_S + white noise; with ``centred_in`` = (a, b) the noise averages to exactly 0
    over the samples a <= t <= b."""
    t = np.arange(int(round(duration * FS_HZ)) + 1) / FS_HZ
    noise = rng.normal(0.0, 1.0, (t.size, 6)) * sigma
    if centred_in is not None:
        inside = (t >= centred_in[0]) & (t <= centred_in[1])
        noise[inside] -= noise[inside].mean(axis=0)
    ring = np.where(t < TRANSIENT_END_S, np.exp(-t / 0.2) * np.cos(2 * np.pi * 3 * t), 0.0)
    return t, mean + noise + ring[:, None] * TRANSIENT


def write_stream(path, t, wrench, torque_unit="Nm"):
    scale = 1e3 if torque_unit == "Nmm" else 1.0
    data = np.column_stack([t, wrench[:, :3], wrench[:, 3:] * scale])
    header = ",".join(["time_s", "Fx_N", "Fy_N", "Fz_N"] + [f"{a}_{torque_unit}" for a in ("Tx", "Ty", "Tz")])
    np.savetxt(path, data, fmt="%.17g", delimiter=",", header=header, comments="")


def write_pcd(path, points):
    """An ASCII PCD of doubles (the layout scanner software writes, with SIZE 8)."""
    head = ("# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 8 8 8\nTYPE F F F\nCOUNT 1 1 1\n"
            f"WIDTH {len(points)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(points)}\nDATA ascii\n")  # fmt: skip
    with open(path, "w") as fh:
        fh.write(head)
        np.savetxt(fh, points, fmt="%.17g")


def write_lab(sim_root, lab, rng, centred=True, torque_unit="Nmm", window=WINDOW_S):
    """A lab's raw files from a simulated dataset: streams (mean = the recorded reading) and clouds
    (unloaded PCD, loaded XYZ, both mm; repeat scans likewise), and the manifest. Returns
    (manifest, {(id, state): (t, w)})."""
    (lab / "ft").mkdir(parents=True)
    (lab / "scans").mkdir()
    (lab / "setup.json").write_text((sim_root / "setup.json").read_text())
    streams, tests = {}, []
    for r in read_tests(sim_root):
        for state, reading in (("unloaded", r.wrench_unloaded), ("loaded", r.wrench_loaded)):
            streams[r.test_id, state] = stream(reading, rng, window if centred else None)
            write_stream(lab / "ft" / f"{r.test_id}_{state}.csv", *streams[r.test_id, state], torque_unit)
        write_pcd(lab / "scans" / f"{r.test_id}_u.pcd", read_ply(r.cloud_unloaded) * 1e3)
        np.savetxt(lab / "scans" / f"{r.test_id}_l.xyz", read_ply(r.cloud_loaded) * 1e3, fmt="%.17g")
        lists = ""
        for state, ext in (("unloaded", "pcd"), ("loaded", "xyz")):
            names = []
            for rep in (x for x in read_repeats(sim_root, state=state) if x.test_id == r.test_id):
                names.append(f"scans/{r.test_id}_{state[0]}_r{rep.repeat}.{ext}")
                points = read_ply(rep.cloud) * 1e3
                if ext == "pcd":
                    write_pcd(lab / names[-1], points)
                else:
                    np.savetxt(lab / names[-1], points, fmt="%.17g")
            if names:
                lists += f"{'' if state == 'unloaded' else 'loaded_'}repeat_clouds = {json.dumps(names)}\n"
        pose = r.scanner_pose
        tests.append(
            f'[[tests]]\nid = "{r.test_id}"\ngroup = "{r.group}"\nq_deg = {json.dumps(r.q_deg.tolist())}\n'
            f"scanner_position_m = {json.dumps(pose[:3, 3].tolist())}\n"
            f"scanner_rotvec_rad = {json.dumps(rotation_vector(pose[:3, :3]).tolist())}\n"
            f'ft_unloaded = "ft/{r.test_id}_unloaded.csv"\nft_loaded = "ft/{r.test_id}_loaded.csv"\n'
            f'cloud_unloaded = "scans/{r.test_id}_u.pcd"\ncloud_loaded = "scans/{r.test_id}_l.xyz"\n{lists}'
        )
    ft = f"window_s = {list(window)}\n" if window else "window_length_s = 1.0\n"
    manifest = lab / "manifest.toml"
    text = f'setup = "setup.json"\n\n[units]\ncloud = "mm"\ntorque = "{torque_unit}"\n\n[ft]\n{ft}\n'
    manifest.write_text(text + "\n".join(tests))
    return manifest, streams


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    """A small simulated dataset (6 identification tests and 1 validation test of the paper scenario,
    seed 5; 2 repeat scans of the unloaded block and 1 of the loaded block per test) and its
    identification (the reference)."""
    root = tmp_path_factory.mktemp("sim") / "dataset"
    data = paper_scenario_data(6, 1, "lab_import", 5, repeats=2, loaded_repeats=1)
    simulate(parse_scenario(data, "lab_import.toml"), root)
    return root, identify_dataset(root)[2]


def test_a_dataset_imported_from_raw_files_identifies_exactly_like_the_simulated_one(
    simulated, tmp_path, capsys
):
    sim_root, reference = simulated
    manifest, _ = write_lab(sim_root, tmp_path / "lab", np.random.default_rng(1))
    out = tmp_path / "imported"
    assert main(["dataset", "import", str(manifest), "--out", str(out)]) == 0
    assert "7 tests (6 identification)" in capsys.readouterr().out
    sim, imp = read_tests(sim_root), read_tests(out)
    for a, b in zip(sim, imp):
        # the window's noise averages to 0: the mean is the recording up to round-off (and N*mm -> N*m)
        for wa, wb in ((a.wrench_unloaded, b.wrench_unloaded), (a.wrench_loaded, b.wrench_loaded)):
            assert np.allclose(wb, wa, rtol=1e-13, atol=1e-12)
        assert np.allclose(b.scanner_pose, a.scanner_pose, atol=1e-15)
        for ca, cb in ((a.cloud_unloaded, b.cloud_unloaded), (a.cloud_loaded, b.cloud_loaded)):
            pa, pb = read_ply(ca), read_ply(cb)  # mm text -> m: a few ulp of a metre
            assert pa.shape == pb.shape and np.abs(pa - pb).max() < 1e-15
    result = identify_dataset(out)[2]
    rel = np.abs(result.stiffness / reference.stiffness - 1)
    print("relative stiffness difference per joint:", rel)
    assert rel.max() < 1e-9  # the fitting is smooth in the data: round-off in, round-off out
    assert np.allclose(result.stiffness_std, reference.stiffness_std, rtol=1e-6)


def test_repeat_scans_import_and_diagnose_like_the_simulated_ones(simulated, tmp_path):
    """The manifest's repeat_clouds and loaded_repeat_clouds: the imported dataset's repeats are
    the simulation's scans (mm text back to m), and the researcher's noise floor and displacements
    against the mean scans (what diagnose tests) equal the simulated dataset's to round-off."""
    from vtestbed.researcher.scan_mean import load_with_floor

    sim_root, _ = simulated
    manifest, _ = write_lab(sim_root, tmp_path / "lab", np.random.default_rng(3))
    out = import_dataset(manifest, tmp_path / "imported").root
    for state, count in (("unloaded", 2), ("loaded", 1)):
        sim, imp = read_repeats(sim_root, state=state), read_repeats(out, state=state)
        assert [(r.test_id, r.repeat) for r in imp] == [(r.test_id, r.repeat) for r in sim]
        assert len(imp) == 7 * count
        for a, b in zip(sim, imp):
            assert np.abs(read_ply(a.cloud) - read_ply(b.cloud)).max() < 1e-15
    (_, ms_sim, floor_sim), (_, ms_imp, floor_imp) = load_with_floor(sim_root), load_with_floor(out)
    assert (floor_imp.n_samples, floor_imp.reference_scans, floor_imp.loaded_scans) == (14, 3, 2)
    # to 1e-9 of each element's scale sqrt(s_ii s_jj): a small off-diagonal element (a weak
    # correlation) carries the diagonal's round-off from the mm text, which is 1e-9 of itself or more
    scale = np.sqrt(np.outer(np.diag(floor_sim.covariance), np.diag(floor_sim.covariance)))
    assert np.all(np.abs(floor_imp.covariance - floor_sim.covariance) <= 1e-9 * scale)
    for a, b in zip(ms_sim, ms_imp):
        assert a.test_id == b.test_id and np.abs(a.displacement - b.displacement).max() < 1e-12
    # the lists are optional: without them no repeats file is written, and the same tests are read
    text = manifest.read_text()
    manifest.write_text("\n".join(line for line in text.splitlines() if "repeat_clouds" not in line))
    bare = import_dataset(manifest, tmp_path / "bare").root
    assert sorted(p.name for p in bare.iterdir()) == ["clouds", "ft_windows.csv", "setup.json", "tests.csv"]
    assert len(list((bare / "clouds").iterdir())) == 14 and read_repeats(bare) == []


def test_averaging_noise_moves_the_stiffness_as_the_readings_it_moves(simulated, tmp_path):
    """Uncentred noise and the automatic window: the imported dataset identifies as the simulated
    one with each reading moved by the mean of the known noise in the window the import chose.

    Against the simulated stiffness: the averaging noise (sem ~2.4e-3 N per reading) is ~1e-5 of
    the ~200 N wire loads, while k_std / k is 1e-3 to 7e-2 here, so the change is expected near
    1 % of k_std; 5 % is the bound (a window in the 25 N ringing would move it by far more)."""
    sim_root, reference = simulated
    manifest, streams = write_lab(
        sim_root, tmp_path / "lab", np.random.default_rng(2), centred=False, window=None
    )
    result = import_dataset(manifest, tmp_path / "imported")
    # the reference: tests.csv of the simulation, readings moved by the known window errors
    lines = (sim_root / "tests.csv").read_text().splitlines()
    header = lines[0].split(",")
    shifted = [lines[0]]
    for line in lines[1:]:
        row = line.split(",")
        tid = row[0]
        for state in ("unloaded", "loaded"):
            r = result.readings[tid, state]
            assert r.automatic and r.start >= TRANSIENT_END_S  # the quietest window is after the ringing
            t, w = streams[tid, state]
            inside = (t >= r.start) & (t <= r.end)
            for i, axis in enumerate(("Fx_N", "Fy_N", "Fz_N", "Tx_Nm", "Ty_Nm", "Tz_Nm")):
                col = header.index(f"{state}_{axis}")
                row[col] = repr(float(w[inside, i].mean()))
        shifted.append(",".join(row))
    ref_root = tmp_path / "shifted"
    shutil.copytree(sim_root / "clouds", ref_root / "clouds")
    (ref_root / "setup.json").write_text((sim_root / "setup.json").read_text())
    (ref_root / "tests.csv").write_text("\n".join(shifted) + "\n")
    shifted_k = identify_dataset(ref_root)[2].stiffness
    k = identify_dataset(tmp_path / "imported")[2].stiffness
    assert np.abs(k / shifted_k - 1).max() < 1e-9
    # and the averaging noise (sem ~ 3e-3 N on 200 N loads) is far below the identification's own
    moved = np.abs(k - reference.stiffness) / reference.stiffness_std
    print("stiffness change / k_std per joint:", moved)
    assert moved.max() < 0.05


def test_a_stream_import_recovers_the_known_mean_and_noise(tmp_path):
    """One 6 s stream with a 1 s ringing: the quietest 2 s window, mean within 4 standard errors of
    the truth, std within 10 % (1000 samples: 2.2 % sampling error), sem within 15 % of sigma/sqrt(n)."""
    rng = np.random.default_rng(7)
    true_mean = np.array([20.0, -3.0, 150.0, 1.2, -0.4, 0.05])
    t, w = stream(true_mean, rng, duration=6.0)
    path = tmp_path / "stream.csv"
    write_stream(path, t, w)
    r = ft_stream.static_reading(ft_stream.read_ft_csv(path), length_s=2.0)
    true_sem = SIGMA / np.sqrt(r.n)
    print(f"window [{r.start:.3f}, {r.end:.3f}] s, n = {r.n}")
    print("(mean - true) / true sem:", (r.mean - true_mean) / true_sem)
    print("std / sigma:", r.std / SIGMA, "sem / true sem:", r.sem / true_sem, "tau:", r.tau)
    assert r.start >= TRANSIENT_END_S and r.n in (1000, 1001)  # 2 s at 500 Hz, both ends in
    assert np.all(np.abs(r.mean - true_mean) < 4 * true_sem)
    assert np.all(np.abs(r.std / SIGMA - 1) < 0.10)
    assert np.all(np.abs(r.sem / true_sem - 1) < 0.15)


def _ar1(rng, n, phi):
    e = rng.normal(0.0, np.sqrt(1 - phi**2), (n, 6))
    x = np.empty((n, 6))
    x[0] = rng.normal(0.0, 1.0, 6)
    for i in range(1, n):
        x[i] = phi * x[i - 1] + e[i]
    return x


def test_the_standard_error_is_honest_for_coloured_noise():
    """AR(1) noise (phi 0.8, a filtered sensor): the true sem is sigma/sqrt(n) * sqrt((1+phi)/(1-phi)),
    3x the white-noise formula. Over 60 seeds x 6 axes the z-scores of the window mean have std in
    [0.85, 1.15] (360 values: 4 % sampling error) and the mean sem estimate is within 10 %."""
    phi, n = 0.8, 5000
    true_sem = np.sqrt((1 + phi) / (1 - phi) / n)
    t = np.arange(n) / FS_HZ
    z, ratio, naive = [], [], []
    for seed in range(60):
        x = _ar1(np.random.default_rng(seed), n, phi)
        r = ft_stream.static_reading(ft_stream.FTStream(None, t, x), window=(0.0, t[-1]))
        z.append(r.mean / r.sem)
        ratio.append(r.sem / true_sem)
        naive.append(r.std / np.sqrt(n) / true_sem)
    print(f"z std {np.std(z):.3f}, sem / true {np.mean(ratio):.3f}, naive / true {np.mean(naive):.3f}")
    assert 0.85 < np.std(z) < 1.15
    assert abs(np.mean(ratio) - 1) < 0.10
    assert np.mean(naive) < 0.4  # what ignoring the autocorrelation would claim


def test_torques_in_nmm_read_as_the_same_wrench_in_nm(tmp_path):
    t, w = stream(np.array([1.0, 2.0, 3.0, 0.4, 0.5, 0.6]), np.random.default_rng(3))
    write_stream(tmp_path / "nm.csv", t, w, "Nm")
    write_stream(tmp_path / "nmm.csv", t, w, "Nmm")
    a = ft_stream.read_ft_csv(tmp_path / "nm.csv").wrench
    b = ft_stream.read_ft_csv(tmp_path / "nmm.csv", "Nmm").wrench
    assert np.allclose(a, w, rtol=1e-15, atol=0) and np.allclose(b, w, rtol=1e-15, atol=1e-18)


def test_clouds_in_each_format_and_unit_read_as_the_points_in_metres(tmp_path):
    from vtestbed._open3d import o3d
    from vtestbed.ply import write_ply

    pts = np.random.default_rng(4).uniform(-0.5, 1.5, (500, 3))  # m
    write_pcd(tmp_path / "a.pcd", pts * 1e3)
    np.savetxt(tmp_path / "a.xyz", pts, fmt="%.17g")
    write_ply(tmp_path / "a.ply", pts, length_unit="mm")
    for name, unit in (("a.pcd", "mm"), ("a.xyz", "m"), ("a.ply", "mm")):
        assert np.abs(read_cloud(tmp_path / name, unit) - pts).max() < 1e-15
    # open3d's own binary PCD stores float32: off by at most half an ulp of float32 (2^-24 relative)
    o3d.io.write_point_cloud(
        str(tmp_path / "b.pcd"), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts * 1e3))
    )
    err = np.abs(read_cloud(tmp_path / "b.pcd", "mm") - pts)
    assert err.max() <= 2.0**-24 * np.abs(pts).max() and err.max() > 0


def test_the_import_modules_never_reach_the_world():
    """The readers sit on the dataset side: a lab without MuJoCo can import its files."""
    for module in ("vtestbed.lab_import", "vtestbed.ft_stream"):
        assert not forbidden_reach(module), forbidden_reach(module)
    probe = "import sys, vtestbed.cli.dataset, vtestbed.lab_import; print('mujoco' in sys.modules, 'open3d' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert out.stdout.split() == ["False", "False"], out.stderr[-2000:]  # open3d only when a PCD/XYZ is read


def test_a_lab_dataset_identifies_without_the_physics_engine(simulated):
    """``vtestbed identify`` on a dataset loads neither MuJoCo nor the truth world
    (vtestbed.dataset_identification), and its numbers are the in-process identification's."""
    root, reference = simulated
    probe = (
        "import json, sys\nfrom vtestbed.cli.main import main\n"
        f"rc = main(['identify', {str(root)!r}, '--quiet', '--no-truth', '--json'])\n"
        "print(json.dumps([rc, 'mujoco' in sys.modules, 'vtestbed.world' in sys.modules]))"
    )
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=300)
    *printed, last = out.stdout.strip().splitlines()
    assert json.loads(last) == [0, False, False], out.stderr[-2000:]
    result = json.loads("\n".join(printed))
    k = np.array(result["stiffness"])  # N*m/rad
    np.testing.assert_allclose(k, reference.stiffness, rtol=1e-12)


# ---------------------------------------------------------------------- bad input: exit 2, no traceback
@pytest.fixture(scope="module")
def lab_files(simulated, tmp_path_factory):
    """A lab folder written from the simulated dataset, whose files the error tests spoil."""
    root = tmp_path_factory.mktemp("labfiles")
    manifest, _ = write_lab(simulated[0], root / "lab", np.random.default_rng(6))
    return root / "lab"


def _spoiled(lab_files, tmp_path, edit):
    lab = tmp_path / "lab"
    shutil.copytree(lab_files, lab)
    edit(lab)
    return lab / "manifest.toml"


def _replace(path, old, new):
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))


def _drifting(lab):
    """Still relaxing: 20 N decaying with a 5 s time constant under the sensor's noise."""
    t = np.arange(2001) / FS_HZ
    w = np.array([1.0, 2.0, 80.0, 0.1, 0.2, 0.3]) + np.exp(-t / 5.0)[:, None] * np.array(
        [0, 0, 20.0, 0, 0, 0]
    )
    w = w + np.random.default_rng(8).normal(0.0, 1.0, w.shape) * SIGMA
    write_stream(lab / "ft" / "T002_loaded.csv", t, w, "Nmm")
    _replace(lab / "manifest.toml", "window_s = [2.0001, 3.5001]", "window_length_s = 1.0")


def _overloaded(lab):
    t = np.arange(2001) / FS_HZ
    w = (
        np.array([1.0, 2.0, 5000.0, 0.0, 0.0, 0.0])
        + np.random.default_rng(0).normal(0.0, 1.0, (2001, 6)) * SIGMA
    )
    write_stream(lab / "ft" / "T003_loaded.csv", t, w, "Nmm")


CASES = {
    "missing column": (
        lambda lab: _replace(lab / "ft" / "T001_loaded.csv", "Fz_N", "Fz"),
        [],
        ["T001_loaded.csv", "column Fz_N is missing", "time_s, Fx_N, Fy_N, Fz_N, Tx_Nmm"],
    ),
    "torque unit": (lambda lab: None, ["--torque-units", "Nm"], ["T001_unloaded.csv", "column Tx_Nm is missing", "Tx_Nmm"]),
    "non-numeric": (
        lambda lab: _replace(lab / "ft" / "T001_unloaded.csv", "\n2.5,", "\nabc,"),
        [],
        ["T001_unloaded.csv line", "column time_s must be a number, got 'abc'"],
    ),
    "window outside": (lambda lab: None, ["--window", "3.0:4.5"], ["T001_unloaded.csv", "window [3, 4.5] s is outside", "0 <= start < end <= 4 s"]),
    "never settles": (_drifting, [], ["T002_loaded.csv", "never settles", "column Fz_N drifts", "<= 5"]),
    "unknown extension": (
        lambda lab: _replace(lab / "manifest.toml", "T001_u.pcd", "T001_u.las"),
        [],
        ["T001_u.las", "unknown point cloud extension '.las'", ".ply, .pcd, .xyz"],
    ),
    "empty cloud": (lambda lab: (lab / "scans" / "T001_l.xyz").write_text(""), [], ["T001_l.xyz", "holds no points"]),
    "cloud in m read as mm": (lambda lab: None, ["--cloud-units", "m"], ["T001_u.pcd", "coordinates reach", "is the file in mm?"]),
    "units in the manifest": (
        lambda lab: _replace(lab / "manifest.toml", 'cloud = "mm"', 'cloud = "cm"'),
        [],
        ["manifest.toml", "units.cloud", "'cm' is not one of m, mm"],
    ),
    "beyond the sensor's range": (_overloaded, [], ["T003_loaded.csv", "Fz = 5000.00 N is outside the measuring range [-990, 990] N"]),
    "missing manifest field": (
        lambda lab: _replace(lab / "manifest.toml", 'ft_loaded = "ft/T001_loaded.csv"\n', ""),
        [],
        ["manifest.toml", "tests[0].ft_loaded: is missing"],
    ),
    "repeat scan listed as the test's own": (
        lambda lab: _replace(lab / "manifest.toml", '"scans/T001_u_r1.pcd"', '"scans/T001_u.pcd"'),
        [],
        ["manifest.toml", "tests[0].repeat_clouds[0]", "is already tests[0].cloud_unloaded", "noise floor too small"],
    ),
    "repeat scans not a list": (
        lambda lab: _replace(lab / "manifest.toml", 'loaded_repeat_clouds = ["scans/T002_l_r1.xyz"]',
                             'loaded_repeat_clouds = "scans/T002_l_r1.xyz"'),
        [],
        ["manifest.toml", "tests[1].loaded_repeat_clouds: must be a list of 0 to 20 cloud files"],
    ),
    "repeat scan missing": (
        lambda lab: (lab / "scans" / "T003_u_r2.pcd").unlink(),
        [],
        ["point cloud file", "T003_u_r2.pcd is missing"],
    ),
    "test id names files": (
        lambda lab: _replace(lab / "manifest.toml", 'id = "T001"', 'id = "../T001"'),
        [],
        ["manifest.toml", "tests[0].id: '../T001' must be letters, digits"],
    ),
}  # fmt: skip


@pytest.mark.parametrize("case", CASES)
def test_bad_input_names_the_file_and_the_field_and_exits_2(case, lab_files, tmp_path, capsys):
    edit, options, expected = CASES[case]
    manifest = _spoiled(lab_files, tmp_path, edit)
    code = main(["dataset", "import", str(manifest), "--out", str(tmp_path / "out"), *options])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err and err.startswith("vtestbed: error: ")
    for text in expected:
        assert text in err, (text, err)
    assert not (tmp_path / "out").exists()  # the clouds converted before the error removed, and their folder


@pytest.mark.parametrize("option", [["--cloud-units", "cm"], ["--window", "3:2"], ["--window-length", "0"]])
def test_bad_options_exit_2_naming_the_option(option, lab_files, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["dataset", "import", str(lab_files / "manifest.toml"), "--out", str(tmp_path / "o"), *option])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and option[0] in err and "Traceback" not in err


def test_the_option_overrides_the_manifest(lab_files, tmp_path):
    """--window overrides [ft] window_s: the reading is the mean of the stream's samples in it."""
    result = import_dataset(lab_files / "manifest.toml", tmp_path / "o", ImportOptions(window=(1.5, 3.9)))
    r = result.readings["T001", "loaded"]
    s = ft_stream.read_ft_csv(lab_files / "ft" / "T001_loaded.csv", "Nmm")
    inside = (s.time >= 1.5) & (s.time <= 3.9)
    assert (r.start, r.end, r.n) == (1.5, 3.9, int(inside.sum())) and r.n == 1201
    assert np.array_equal(r.mean, s.wrench[inside].mean(axis=0))


def test_a_slow_drift_is_refused_unless_the_threshold_allows_it(tmp_path):
    """0.2 N/s on Fz (a relaxing wire): the halves of a 1 s window differ by 0.1 N, about 18 standard
    errors of white noise of 0.0625 N at 500 Hz; refused at z 5, accepted at z 30 with the window's
    plain mean (the drift's value at the window's centre)."""
    t = np.arange(2001) / FS_HZ
    w = np.array([5.0, 1.0, 80.0, 0.1, 0.2, 0.3]) + np.outer(0.2 * t, [0, 0, 1.0, 0, 0, 0])
    w = w + np.random.default_rng(9).normal(0.0, 1.0, w.shape) * SIGMA
    write_stream(tmp_path / "s.csv", t, w)
    s = ft_stream.read_ft_csv(tmp_path / "s.csv")
    with pytest.raises(ft_stream.DatasetError, match=r"column Fz_N drifts by 0\.\d+ N"):
        ft_stream.static_reading(s, (2.0001, 3.0001))
    r = ft_stream.static_reading(s, (2.0001, 3.0001), settle_z=30.0)
    assert abs(r.mean[2] - (80.0 + 0.2 * 2.5001)) < 4 * SIGMA[2] / np.sqrt(r.n)


def test_an_inline_setup_table_gives_the_same_setup(lab_files, tmp_path):
    """[setup] in the manifest instead of a setup.json path: the dataset's setup.json is the same."""
    from vtestbed.dataset import read_setup

    lab = tmp_path / "lab"
    shutil.copytree(lab_files, lab)
    setup = json.loads((lab / "setup.json").read_text())
    fs = setup["force_sensor"]
    table = (
        f'\n[setup]\nrobot = "{setup["robot"]}"\nangle_convention = "{setup["angle_convention"]}"\n'
        f"block_in_flange = {json.dumps(setup['block_in_flange'])}\n"
        f"sensor_in_flange = {json.dumps(setup['sensor_in_flange'])}\nblock_edge_m = {setup['block_edge_m']!r}\n"
        f'force_sensor = {{ name = "{fs["name"]}", range_N_Nm = {json.dumps(fs["range_N_Nm"])} }}\n'
    )
    text = (lab / "manifest.toml").read_text().replace('setup = "setup.json"\n', "")
    (lab / "manifest.toml").write_text(table + text)
    import_dataset(lab / "manifest.toml", tmp_path / "o")
    a, b = read_setup(lab_files), read_setup(tmp_path / "o")
    assert np.array_equal(a.block_in_flange, b.block_in_flange) and a.sensor_range == b.sensor_range
    assert (a.robot, a.block_edge, a.angle_convention) == (b.robot, b.block_edge, b.angle_convention)
    # no reading noise in the table: the windows' own, per axis the RMS of ft_windows.csv's standard errors
    with open(tmp_path / "o" / "ft_windows.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    sem = np.array([[float(r[k]) for k in r if "_sem_" in k] for r in rows])
    assert sem.shape == (2 * len(read_tests(tmp_path / "o")), 6)
    np.testing.assert_allclose(b.sensor_noise_std, np.sqrt(np.mean(sem**2, axis=0)), rtol=1e-12)
    assert (
        a.sensor_noise_std is not None and b.sensor_noise_std != a.sensor_noise_std
    )  # a stated one is kept, above
