"""One writer per folder (issue 13): a second ``simulate`` into a dataset folder, or a second sweep
into a results folder, is refused at once naming the first writer's process id; two real processes."""

import subprocess
import sys
from pathlib import Path

import pytest

from vtestbed.campaigns.store import SweepError
from vtestbed.errors import DatasetError
from vtestbed.files import LOCK_FILE, folder_lock

ROOT = Path(__file__).resolve().parents[1]
HOLDER = """
import sys
from vtestbed.files import folder_lock
from vtestbed.errors import DatasetError
with folder_lock(sys.argv[1], "folder", DatasetError):
    print("locked", flush=True)
    sys.stdin.readline()  # hold the lock until the test says so
"""


@pytest.fixture
def holder(tmp_path):
    """Another process holding the lock on tmp_path/'out' until the test ends: (folder, its pid)."""
    out = tmp_path / "out"
    out.mkdir()
    proc = subprocess.Popen([sys.executable, "-c", HOLDER, str(out)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)  # fmt: skip
    assert proc.stdout.readline().strip() == "locked"
    yield out, proc.pid
    proc.stdin.write("\n")
    proc.stdin.close()
    assert proc.wait(timeout=30) == 0


def test_a_second_simulate_into_a_locked_dataset_folder_exits_2(holder):
    out, pid = holder
    scenario = ROOT / "scenarios" / "kr60_ideal.toml"
    done = subprocess.run([sys.executable, "-m", "vtestbed", "simulate", str(scenario), "--out", str(out), "--quiet"],
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip() == (
        f"vtestbed: error: dataset folder {out} is being written by another process (pid {pid}); "
        "wait for it to finish, or choose another folder"
    )
    assert sorted(p.name for p in out.iterdir()) == [LOCK_FILE]  # nothing was written


def test_a_second_sweep_into_a_locked_results_folder_is_refused(holder):
    from quick_campaign import tiny

    from vtestbed.campaigns.runner import sweep

    out, pid = holder
    with pytest.raises(
        SweepError, match=rf"results folder .* is being written by another process \(pid {pid}\)"
    ):
        sweep(tiny(), out, workers=1, progress=False)
    assert not (out / "campaign.json").exists()


def test_the_lock_is_released_and_reentrant_after_use(tmp_path):
    with folder_lock(tmp_path, "folder", DatasetError) as path:
        assert path.read_text() == str(__import__("os").getpid())
        with pytest.raises(DatasetError, match=r"is being written by another process \(pid \d+\)"):
            with folder_lock(tmp_path, "folder", DatasetError):  # a second open file description
                pass
    assert path.read_text() == ""
    with folder_lock(tmp_path, "folder", DatasetError):  # free again
        pass
