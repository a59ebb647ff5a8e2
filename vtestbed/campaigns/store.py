"""A campaign's results folder: the manifest, the Parquet parts, and the fingerprints that keep
results of different campaigns or different code apart.

Layout::

    DIR/campaign.json         manifest: campaign, fingerprints, the drawn test plans, plan quality
    DIR/trials/part-*.parquet one file per finished batch, one row per trial

Every file is written atomically (:func:`vtestbed.files.write_atomic`), so a killed run leaves
finished batches whole and nothing half-written; rows are keyed by ``trial_key`` and
deduplicated on reading, so a resumed run never counts a trial twice.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import VtestbedError
from ..files import read_json, write_atomic, write_json_atomic
from ..robots import robot_dir
from ..world.truth import load_truth
from .posesets import TestPlan, build_plans, plan_prior, plan_quality
from .spec import AXES, Campaign

if TYPE_CHECKING:
    import pandas as pd

MANIFEST = "campaign.json"
TRIALS_DIR = "trials"


class SweepError(VtestbedError, ValueError):
    """A results folder that belongs to another campaign, or a failed execution setting."""


def write_part(out: Path, name: str, frame: pd.DataFrame) -> Path:
    """Write one finished batch as ``out/trials/<name>.parquet`` (atomically)."""
    return write_atomic(out / TRIALS_DIR / f"{name}.parquet", lambda p: frame.to_parquet(p, index=False))


def remove_stale_parts(out: Path) -> None:
    """Delete temporary files of writes that a killed run cut short."""
    for stale in (out / TRIALS_DIR).glob(".part-*.tmp-*"):
        stale.unlink(missing_ok=True)


def read_results(out: str | Path) -> pd.DataFrame:
    """Every trial in ``out/trials`` (one row per trial key; duplicates dropped)."""
    import pandas as pd  # imported here: a campaign worker imports this package, never pandas

    parts = sorted((Path(out) / TRIALS_DIR).glob("part-*.parquet"))
    if not parts:
        return pd.DataFrame(columns=["trial_key"])
    df = pd.concat([_read_part(p) for p in parts], ignore_index=True)
    df = df.sort_values("trial_key", kind="stable").drop_duplicates("trial_key", keep="first")
    return df.sort_values([*AXES, "trial"], kind="stable").reset_index(drop=True)


def _read_part(path: Path) -> pd.DataFrame:
    """One Parquet part, or a SweepError naming it (a truncated or foreign file)."""
    import pandas as pd

    try:
        frame = pd.read_parquet(path)
    except Exception as exc:  # pyarrow raises several types (ArrowInvalid, OSError, ...)
        raise SweepError(
            f"{path}: not a readable Parquet part ({type(exc).__name__}: {str(exc)[:120]}); "
            "delete it and rerun the sweep to recompute its trials"
        ) from None
    if "trial_key" not in frame.columns:
        raise SweepError(
            f"{path}: a Parquet part without the trial_key column; delete it and rerun the sweep"
        )
    return frame


def code_fingerprint(robot: str) -> str:
    """Hash of the source that shapes a trial's numbers (package modules but the CLI and reports,
    and the model files of the campaign's ``robot``): results of different code are not mixed in
    one folder. Other robots' files are left out: importing a robot must not block resuming the
    sweeps of the robots already there."""
    package = Path(__file__).resolve().parents[1]
    files = [p for p in sorted(package.rglob("*.py")) if not _reporting_only(p.relative_to(package))]
    files += sorted(robot_dir(robot).glob("*.toml"))
    h = hashlib.sha256()
    for p in files:
        name = p.relative_to(package) if p.is_relative_to(package) else Path(p.parent.name, p.name)
        h.update(str(name).encode() + b"\0" + p.read_bytes())
    return h.hexdigest()[:16]


def _reporting_only(relative: Path) -> bool:
    """Modules that cannot change a trial's numbers: the CLI, reports and figures."""
    return relative.parts[0] in ("cli", "reports") or relative.stem in (
        "report",
        "plots",
        "plotting",
        "comparison",
    )


def open_manifest(out: Path, campaign: Campaign, allow_code_change: bool) -> dict:
    path = out / MANIFEST
    code = code_fingerprint(campaign.scenario.robot_name)
    if path.exists():
        manifest = read_json(path, "campaign manifest", SweepError)
        for key in ("plans", "plan_quality"):
            if not isinstance(manifest.get(key), dict):
                raise SweepError(
                    f"{path}: {key} must be a table (a corrupt manifest); delete the folder {out} "
                    "or choose a new --out folder"
                )
        if manifest.get("fingerprint") != campaign.fingerprint:
            raise SweepError(
                f"{out} holds results of another campaign (fingerprint {manifest.get('fingerprint')} != "
                f"{campaign.fingerprint}: base scenario, seed, pairing or pose-set options differ); "
                "choose a new --out folder"
            )
        if manifest.get("code_fingerprint") != code and not allow_code_change:
            raise SweepError(
                f"{out} holds results of other vtestbed code (code fingerprint {manifest.get('code_fingerprint')} "
                f"!= {code}: the pipeline's source or the robot model changed since); choose a new --out "
                "folder, or allow_code_change=True (--allow-code-change) to mix them knowingly"
            )
        return manifest
    robot = campaign.scenario.robot
    k_true = load_truth(robot.name).stiffness_true
    return {"format": 1, "fingerprint": campaign.fingerprint, "code_fingerprint": code, "scenario": campaign.scenario.name,
            "reference": campaign.scenario.reference,  # what every trial's displacements are measured from
            "joint_names": list(robot.joint_names), "stiffness_true_Nm_per_rad": k_true.tolist(),
            "campaign": campaign.to_dict(), "plans": {}, "plan_quality": {}}  # fmt: skip


def plans_on_disk(out: Path, campaign: Campaign, manifest: dict, log) -> dict[str, TestPlan]:
    keys = {campaign.plan_key(c) for c in campaign.cells()}
    missing = sorted(keys - set(manifest["plans"]))
    if missing:
        for key, plan in build_plans(campaign, missing, progress=log).items():
            manifest["plans"][key] = plan.to_dict()
    plans = {k: TestPlan.from_dict(manifest["plans"][k]) for k in keys}
    sc = campaign.scenario
    prior = plan_prior(campaign)
    for c in campaign.cells():
        qkey = f"{c.pose_set}:{c.n_tests}"
        if qkey not in manifest["plan_quality"]:
            plan = plans[campaign.plan_key(c)]
            manifest["plan_quality"][qkey] = plan_quality(sc.robot, plan, c.n_tests, sc.lab, prior)
    manifest["campaign"] = campaign.to_dict()
    out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out / MANIFEST, manifest)
    return plans


def results(out: str | Path, campaign: Campaign | None = None) -> pd.DataFrame:
    """The trials on disk; with ``campaign``, only that campaign's cells and trials."""
    df = read_results(out)
    if campaign is None or df.empty:
        return df
    keys = {f"{c.key};trial={t}" for c in campaign.cells() for t in range(campaign.trials)}
    return df[df["trial_key"].isin(keys)].reset_index(drop=True)
