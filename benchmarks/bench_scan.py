"""Median time to scan (ray-cast) and to process one cloud of about 50k block points, on one core.

Run: .venv/bin/python benchmarks/bench_scan.py [--repeats 30]

Threads are pinned to one (OMP/TBB) before open3d is imported, so the numbers are per core.
"""

from __future__ import annotations

import os

# before numpy (imported by _timing) starts its BLAS threads
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "TBB_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402

import numpy as np  # noqa: E402
from _timing import median_time  # noqa: E402  (benchmarks/ is on sys.path when run as a script)

from vtestbed._open3d import o3d  # noqa: E402
from vtestbed.researcher import cloud, cloud_ransac  # noqa: E402
from vtestbed.transforms import invert  # noqa: E402
from vtestbed.world.rig import Rig  # noqa: E402
from vtestbed.world.scan_noise import ScanNoise  # noqa: E402
from vtestbed.world.scanner import BLOCK_GEOM, Scanner  # noqa: E402

SPACING_M = 0.47e-3  # about 50k points on the block at 0.6 m


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=30)
    n = parser.parse_args().repeats

    rig = Rig()
    rig.command(np.radians([0, -60, -20, 30, 50, 45]))
    rig.hook("hook_x", "ring_5")
    state = rig.solve()
    scanner = Scanner.place(rig.lab, state.block_pose, point_spacing_m=SPACING_M)
    hits = scanner.cast(rig.model, rig.data)
    n_rays, n_block = len(scanner.ray_directions), int(np.sum(hits.geom_ids == rig.model.geom(BLOCK_GEOM).id))
    t_cast = median_time(lambda: scanner.cast(rig.model, rig.data), n)
    noise = ScanNoise()
    rng = np.random.default_rng(0)
    t_noise = median_time(lambda: noise.apply(hits, rng), n)
    points = noise.apply(hits, np.random.default_rng(1))
    nominal = invert(scanner.pose_world) @ state.block_pose
    t_fit = median_time(lambda: cloud.fit_block_frame(points, nominal), n)
    ransac = cloud.FitParams(method="ransac")
    t_ransac_fit = median_time(lambda: cloud.fit_block_frame(points, nominal, ransac), n)

    # Where the processing time goes: the same steps, timed one by one.
    params = cloud.FitParams()
    q = nominal[:3, :3].T @ (points - nominal[:3, 3]).T  # columns (3, N) in the nominal block frame
    q = q[:, (q.min(axis=0) >= -0.09) & (q.max(axis=0) <= 0.01)]
    t_sor = median_time(lambda: cloud_ransac.remove_outliers(q, params), n)
    face = np.ascontiguousarray(q[:, np.abs(q[2]) < 1e-4].T)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(face))
    t_ransac = 3 * median_time(
        lambda: pcd.segment_plane(params.ransac_threshold_m, 3, params.ransac_iterations), n
    )
    t_per_point = median_time(
        lambda: cloud.fit_block_frame(points, nominal, cloud.FitParams(method="ransac", sor_voxel_m=0.0)), 5
    )

    print(
        f"scene: {rig.model.ngeom} geoms; scan window {n_rays} rays, {len(hits)} hits, {n_block} on the block"
    )
    print(
        f"ray cast (mj_multiRay, 1 thread):     {t_cast * 1e3:7.2f} ms  ({n_rays / t_cast / 1e6:.1f} Mray/s)"
    )
    print(f"noise draw ({len(hits)} points):        {t_noise * 1e3:7.2f} ms")
    print(
        f"process one cloud ({len(points)} points):  {t_fit * 1e3:7.2f} ms  (fit_block_frame, fast path, median of {n})"
    )
    print("  (benchmarks/bench_cloud.py: the fast path against RANSAC, accuracy, CPU time)")
    print(
        f"RANSAC fallback, one cloud:             {t_ransac_fit * 1e3:7.2f} ms  (FitParams(method='ransac'))"
    )
    print(f"  statistical outlier removal (voxel):  {t_sor * 1e3:7.2f} ms")
    print(f"  RANSAC segment_plane, 3 faces:        {t_ransac * 1e3:7.2f} ms")
    print(f"  rest (crop, seeding, SVD fits, MAD):  {(t_ransac_fit - t_sor - t_ransac) * 1e3:7.2f} ms")
    print(f"  (per-point outlier removal instead:   {t_per_point * 1e3:7.2f} ms)")
    print(
        "limits: the cast is bound by mj_multiRay's per-ray cost over every geom of the scene (about half\n"
        "the window's rays miss the block). It releases the GIL but allocates on the MjData stack, so\n"
        "threads over ray chunks need one MjData each;\n"
        "the fast fit is bound by numpy passes over the cloud (crop, reassignment, three face fits); the\n"
        "RANSAC fallback by open3d's k-d tree in the outlier removal."
    )


if __name__ == "__main__":
    main()
