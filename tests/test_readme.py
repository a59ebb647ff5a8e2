"""The README's set-up commands are what CI runs, and its Python example uses the public API."""

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

import vtestbed

ROOT = Path(__file__).resolve().parents[1]


def _readme_commands():
    text = (ROOT / "README.md").read_text()
    return re.findall(r"```bash\n(.+?)\n```", text)[:2]


def test_readme_opens_with_main_job_and_test_commands():
    main_job, tests = _readme_commands()
    assert "pip install" in main_job and "vtestbed " in main_job
    assert "pip install" in tests and "pytest" in tests


def test_ci_runs_the_readme_test_command():
    _, tests = _readme_commands()
    ci = (ROOT / ".ci" / "run").read_text()
    assert tests in ci.splitlines()


def _python_example() -> str:
    return re.findall(r"```python\n(.+?)\n```", (ROOT / "README.md").read_text(), re.S)[0]


def test_python_example_uses_only_the_top_level_entry_points():
    tree = ast.parse(_python_example())
    used = {
        n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute) and getattr(n.value, "id", "") == "vt"
    }
    assert used and used <= set(vtestbed.__all__), sorted(used - set(vtestbed.__all__))
    assert len(_python_example().splitlines()) <= 12


@pytest.mark.slow
def test_python_example_runs(tmp_path):
    code = _python_example().replace('"runs/', f'"{tmp_path}/')
    code = code.replace('"scenarios/', f'"{ROOT}/scenarios/')
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=600
    )
    assert out.returncode == 0, out.stderr[-2000:]
    rows = [line for line in out.stdout.splitlines() if line.startswith("joint")]
    assert len(rows) >= 12  # six joints printed, then the six rows of Table 5


def test_the_demo_prints_the_table_the_readme_shows(tmp_path, capsys):
    """The README's Table 5 block is the demo's output (a drift test: the convergence columns
    moved on 2026-11-29 with the few-test weights, and no test said so)."""
    from vtestbed.cli.main import main

    assert (
        main(["run", str(ROOT / "scenarios" / "kr60_paper.toml"), "--out", str(tmp_path / "run"), "--quiet"])
        == 0
    )
    printed = [
        line for line in capsys.readouterr().out.splitlines() if line.startswith(("joint", "validation"))
    ]
    block = re.search(r"```\n(joint     k_true.+?)\n```", (ROOT / "README.md").read_text(), re.S).group(1)
    assert printed == block.splitlines()
