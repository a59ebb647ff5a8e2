"""Start-up: what importing the package's entry points loads (fresh interpreters, sys.modules), and
the command table that lets ``vtestbed CMD`` import only CMD's module."""

from __future__ import annotations

import argparse
import importlib
import json
import subprocess
import sys

import pytest

cli_main = importlib.import_module("vtestbed.cli.main")  # the module (vtestbed.cli.main is also a function)

PROBE = "import importlib, json, sys\nfor m in sys.argv[1:]: importlib.import_module(m)\nprint(json.dumps(sorted(sys.modules)))"


def _loaded(*modules: str) -> set[str]:
    """Top-level packages loaded by a fresh interpreter that imports ``modules``."""
    out = subprocess.run([sys.executable, "-c", PROBE, *modules], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    return {m.split(".")[0] for m in json.loads(out.stdout)} | {m for m in json.loads(out.stdout)}


@pytest.mark.parametrize(
    "modules, absent",
    [
        # what a campaign worker unpickles and runs
        (
            ("vtestbed.campaigns.worker",),
            ("pandas", "pyarrow", "matplotlib", "dash", "plotly", "dask", "tqdm"),
        ),
        (("vtestbed.campaigns",), ("pandas", "pyarrow", "matplotlib", "mujoco", "scipy")),  # lazy names
        (("vtestbed.ply",), ("open3d", "mujoco", "pandas")),  # PLY files in numpy alone
        (("vtestbed._open3d",), ("dash", "plotly", "pandas")),  # open3d without its plotly viewer
        (("vtestbed", "vtestbed.cli.main"), ("mujoco", "open3d", "pandas", "scipy")),
    ],
)
def test_entry_points_do_not_load_what_they_do_not_use(modules, absent):
    loaded = _loaded(*modules)
    assert modules[0] in loaded  # the probe really imported it
    assert not loaded & set(absent), sorted(loaded & set(absent))


def test_open3d_plotly_functions_still_work_on_first_use():
    code = (
        "import sys\nfrom vtestbed._open3d import o3d\nimport numpy as np\n"
        "assert 'plotly' not in sys.modules\n"
        "pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.eye(3)))\n"
        "fig = o3d.visualization.get_plotly_fig([pc])\n"
        "print(len(fig.data[0].x), 'plotly' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["3", "True"]  # three points drawn, plotly loaded on demand


def test_the_command_table_names_every_command_of_its_module():
    registered = {}
    for name in cli_main.COMMAND_MODULES:
        sub = argparse.ArgumentParser().add_subparsers()
        __import__(name, fromlist=["register"]).register(sub)
        registered.update(dict.fromkeys(sub.choices, name))
    assert registered == cli_main.COMMANDS
    # one command's parser alone parses as the full parser does
    args = cli_main.build_parser("sweep").parse_args(["sweep", "c.toml", "--out", "o", "--workers", "2"])
    full = cli_main.build_parser().parse_args(["sweep", "c.toml", "--out", "o", "--workers", "2"])
    assert vars(args) == vars(full) and args.workers == 2
