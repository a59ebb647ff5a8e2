"""docs/errors.md, command-line rows: each bad option value, output path, pipe or second writer given
to the real ``vtestbed`` command in-process (``vtestbed.cli.main.main``): exit 2 (1 for a file-system
error, 0 for a closed pipe), one error line, no traceback, nothing written."""

from __future__ import annotations

import io
import json
import os
import sys

import pytest
from errors_table import Ctx, cli, run_row, section_rows
from quick_campaign import QUICK
from test_errors_table_scenario import scenario

from vtestbed.errors import DatasetError
from vtestbed.files import LOCK_FILE, folder_lock

ROWS = section_rows("Command line (exit 2)", "One writer per folder")
PAPER_PRIOR = ["--stiffness-prior", "paper_table5"]


def command(*argv, files=()):
    """A case: ``vtestbed argv`` ({tmp} is the case's folder, which holds ``afile``, a file, and
    ``ragged.json``); nothing may be written there."""

    def case(ctx: Ctx):
        (ctx.tmp / "afile").write_text("not a folder")
        (ctx.tmp / "ragged.json").write_text(json.dumps({"q_deg": [[0, -60, -20, 30, 50, 45], [0, 1]]}))
        line = cli(ctx, [a.replace("{tmp}", str(ctx.tmp)) for a in argv])
        assert sorted(p.name for p in ctx.tmp.iterdir()) == ["afile", "ragged.json", *files]
        return line

    return case


def _scheduler(ctx: Ctx):
    path = ctx.tmp / "quick.toml"
    path.write_text(QUICK)
    return cli(ctx, ["sweep", path, "--out", ctx.tmp / "out", "--scheduler", "not a url", "--quiet"])


def _stdout(ctx: Ctx, stream, code: int) -> str:
    """``vtestbed poses criterion`` printing into ``stream``: its exit code and stderr."""
    from vtestbed.cli.main import main

    saved, sys.stdout = sys.stdout, stream
    try:
        got = main(["poses", "criterion", "--q-deg", "0,-30,-20,40,60,45"])
    finally:
        sys.stdout = saved
    err = ctx.capsys.readouterr().err
    assert got == code and "Traceback" not in err, err
    return err.strip()


def _closed_pipe(ctx: Ctx):
    """stdout a pipe whose reader is gone (``vtestbed ... | head``): silence, exit 0."""
    read, write = os.pipe()
    os.close(read)
    stream = io.TextIOWrapper(io.FileIO(write, "w"), write_through=False)
    try:
        err = _stdout(ctx, stream, 0)
    finally:
        try:
            stream.close()
        except BrokenPipeError:
            pass
    return err or "nothing"


def _disk_full(ctx: Ctx):
    """stdout on /dev/full: the file system's own error, exit 1."""
    with open("/dev/full", "w") as stream:
        err = _stdout(ctx, stream, 1)
        try:
            stream.close()
        except OSError:
            pass
    return err


def _locked_simulate(ctx: Ctx):
    """A second writer (``simulate``) into a dataset folder that another writer holds locked."""
    out = ctx.tmp / "ds"
    out.mkdir()
    path = scenario(ctx)
    with folder_lock(out, "folder", DatasetError):  # the first writer (another open file description)
        line = cli(ctx, ["simulate", path, "--out", out, "--quiet"])
    assert sorted(p.name for p in out.iterdir()) == [LOCK_FILE]  # nothing written
    return line


def _locked_sweep(ctx: Ctx):
    path = ctx.tmp / "quick.toml"
    path.write_text(QUICK)
    out = ctx.tmp / "out"
    out.mkdir()
    with folder_lock(out, "folder", DatasetError):
        line = cli(ctx, ["sweep", path, "--out", out, "--quiet", "--workers", "1"])
    assert not (out / "campaign.json").exists()
    return line


def _made_by(*markers: str):
    """A folder holding what another command writes first (``campaign.json``, ``trials/``,
    ``truth.json``, ``result.json``; empty files: only the names tell what a folder holds)."""

    def folder(ctx: Ctx):
        out = ctx.tmp / "other"
        for marker in markers:
            path = out / marker
            path.parent.mkdir(parents=True, exist_ok=True)
            if marker.endswith("/"):
                path.mkdir()
            else:
                path.write_text("{}")
        return out

    return folder


def _into(command: str, folder):
    """A case: ``vtestbed command ... --out`` a folder another command made; nothing in it changes."""

    def case(ctx: Ctx):
        out = folder(ctx)
        before = sorted(str(p.relative_to(out)) for p in out.rglob("*"))
        path = ctx.tmp / "quick.toml"
        if command == "sweep":
            path.write_text(QUICK)
        else:
            path = scenario(ctx)
        line = cli(ctx, [command, path, "--out", out, "--quiet"])
        after = sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.name != LOCK_FILE)
        assert after == before
        return line

    return case


CASES = {
    "opt-seed-negative": command("poses", "optimize", "--seed", "-1"),
    "opt-scan-seed-negative": command("scan", "--out", "{tmp}/s", "--seed", "-1"),
    "opt-jitter-nan": command("poses", "regions", "--wrist-jitter-deg", "nan"),
    "opt-q6-nan": command("poses", "optimize", "--q6-deg", "nan"),
    "opt-q6-huge": command("poses", "optimize", "--q6-deg", "1e9"),
    "opt-q6-limits": command("poses", "optimize", "--q6-deg", "355"),
    "opt-batch-trials": command("sweep", "x.toml", "--out", "{tmp}/sw", "--batch-trials", "-5"),
    "opt-workers": command("sweep", "x.toml", "--out", "{tmp}/sw", "--workers", "0"),
    "opt-tension": command("load", "--tension", "inf"),
    "opt-distance": command("scan", "--out", "{tmp}/s", "--distance-mm", "0"),
    "opt-q-deg-count": command("load", "--q-deg", "0,-60,-20,30,50"),
    "opt-q-deg-word": command("load", "--q-deg", "0,-60,-20,30,fifty,45"),
    "opt-q-deg-limits": command("load", "--q-deg", "0,-60,-20,30,130,45"),
    "opt-load-singular": command("load", "--q-deg", "0,-60,-20,30,0,45"),
    "opt-scan-singular": command("scan", "--out", "{tmp}/s", "--q-deg", "0,-60,-20,30,0,45"),
    "opt-load-arm-in-floor": command("load", "--q-deg", "0,20,-60,0,60,0"),
    "out-is-file": command("simulate", "x.toml", "--out", "{tmp}/afile"),
    "out-under-file": command("run", "x.toml", "--out", "{tmp}/afile/sub"),
    "out-not-writable": command("poses", "optimize", "--out", "/proc/vtestbed/x"),
    "design-poses-missing": command("poses", "design", *PAPER_PRIOR, "--poses", "{tmp}/none.json"),
    "design-poses-not-json": command("poses", "design", *PAPER_PRIOR, "--poses", "{tmp}/afile"),
    "design-poses-ragged": command("poses", "design", *PAPER_PRIOR, "--poses", "{tmp}/ragged.json"),
    "design-region-option-random-pool": command("poses", "design", *PAPER_PRIOR, "--box", "1,2,3"),
    "design-prior-negative": command("poses", "design", "--stiffness-prior=-1,2,3,4,5,6"),
    "diagnose-scale-tolerance-negative": command("diagnose", "{tmp}/ds", "--scale-tolerance=-5"),
    "diagnose-rank-unknown": command("diagnose", "{tmp}/ds", "--rank", "aic"),
    "diagnose-candidates-none-and-names": command(
        "diagnose", "{tmp}/ds", "--candidates", "none,link_compliance"
    ),
    "discover-extra-tests-zero": command(
        "discover", "{tmp}/s.toml", "--out", "{tmp}/o", "--extra-tests", "0"
    ),
    "discover-scale-tolerance-too-large": command(
        "discover", "{tmp}/s.toml", "--out", "{tmp}/o", "--scale-tolerance", "40000"
    ),
    "scheduler-not-a-url": _scheduler,
    "closed-pipe": _closed_pipe,
    "disk-full": _disk_full,
    "report-out-not-writable": command("report", "{tmp}", "--out", "/proc/vtestbed/report.html"),
    "lock-simulate": _locked_simulate,
    "folder-of-a-sweep": _into("simulate", _made_by("campaign.json", "trials/")),
    "folder-of-a-simulation": _into("run", _made_by("truth.json")),
    "folder-of-a-run": _into("sweep", _made_by("result.json")),
    "lock-sweep": _locked_sweep,
}


@pytest.mark.parametrize("key", sorted(set(ROWS) | set(CASES)))
def test_documented_message_is_the_codes(key, tmp_path, capsys):
    run_row(CASES, ROWS, key, Ctx(tmp_path, capsys))
