"""The two sides of the lab are enforced, not described (docs/architecture.md, "Contracts").

An AST walk over the package builds its import graph (imports inside functions included, and a
module also runs its parent packages' ``__init__``). The contracts:

1. ``vtestbed.researcher`` never reaches ``vtestbed.world`` or mujoco, directly or through
   another module: it must run on a lab's dataset with no simulator installed.
2. ``vtestbed.dataset`` (the only crossing between the sides) never reaches the world either.
3. Only the world, the orchestrators (``experiment``, ``campaigns``, ``cli``) and the truth
   comparison (``comparison``) read the truth: the true-stiffness loader, the truth file reader
   and the ``stiffness_true`` values appear nowhere else.

Plus a fresh interpreter check: importing ``vtestbed.researcher`` loads no mujoco module.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "vtestbed"
WORLD = "vtestbed.world"
TRUTH_READERS = (
    "vtestbed.world",
    "vtestbed.experiment",
    "vtestbed.comparison",
    "vtestbed.campaigns",
    "vtestbed.cli",
)
TRUTH_NAMES = ("load_truth", "read_truth", "RobotTruth", "stiffness_true")


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def _resolve(module: str, node: ast.ImportFrom) -> list[str]:
    """Absolute names a ``from ... import`` statement in ``module`` loads."""
    is_package = MODULES[module].name == "__init__.py"
    if node.level:
        base = module.split(".")
        base = base[: len(base) - node.level + (1 if is_package else 0)]
        target = ".".join(base + ([node.module] if node.module else []))
    else:
        target = node.module or ""
    names = [target]
    for alias in node.names:  # "from . import cloud" loads the submodule vtestbed.<pkg>.cloud
        if f"{target}.{alias.name}" in MODULES:
            names.append(f"{target}.{alias.name}")
    return names


def imports(module: str) -> set[str]:
    """Every module ``module`` imports (absolute names; third-party ones by their top name)."""
    out = set()
    for node in ast.walk(ast.parse(MODULES[module].read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            out |= set(_resolve(module, node))
    return out


def _with_parents(name: str) -> list[str]:
    parts = name.split(".")
    return [".".join(parts[:i]) for i in range(1, len(parts) + 1)]


def reach(start: str) -> dict[str, str]:
    """Everything ``start`` loads, transitively, mapped to the module that imports it first."""
    seen, stack = {start: ""}, [start]
    while stack:
        current = stack.pop()
        targets = imports(current) if current in MODULES else set()
        for target in sorted(targets):
            for name in _with_parents(target):
                if name not in seen:
                    seen[name] = current
                    if name in MODULES:
                        stack.append(name)
    return seen


def chain(seen: dict[str, str], target: str) -> str:
    """``a -> b -> target``: how the first module reaches ``target``."""
    path = [target]
    while seen.get(path[-1]):
        path.append(seen[path[-1]])
    return " -> ".join(reversed(path))


def forbidden_reach(start: str) -> list[str]:
    seen = reach(start)
    bad = sorted(n for n in seen if n == "mujoco" or n == WORLD or n.startswith(WORLD + "."))
    return [chain(seen, b) for b in bad]


@pytest.mark.parametrize("module", sorted(m for m in MODULES if m.startswith("vtestbed.researcher")))
def test_the_researcher_side_never_reaches_the_world_or_mujoco(module):
    bad = forbidden_reach(module)
    assert not bad, (
        f"{module} reaches the truth world: {bad[0]}. The researcher side reads datasets only; "
        "move shared code to a top-level module (lab, transforms, dataset) instead"
    )


def test_the_dataset_format_never_reaches_the_world():
    for module in (
        "vtestbed.dataset",
        "vtestbed.dataset_repeats",
        "vtestbed.ply",
        "vtestbed.lab_import",
        "vtestbed.lab_manifest",
        "vtestbed.ft_stream",
        "vtestbed.dataset_identification",
    ):
        bad = forbidden_reach(module)
        assert not bad, f"{module} (the crossing between the sides) reaches the world: {bad[0]}"


def _truth_uses(module: str) -> list[str]:
    tree = ast.parse(MODULES[module].read_text())
    found = []
    for node in ast.walk(tree):
        name = (
            node.id if isinstance(node, ast.Name) else node.attr if isinstance(node, ast.Attribute) else None
        )
        if isinstance(node, ast.ImportFrom):
            found += [f"imports {a.name}" for a in node.names if a.name in TRUTH_NAMES]
            found += [
                f"imports {t}"
                for t in _resolve(module, node)
                if t in ("vtestbed.world.truth", "vtestbed.comparison")
            ]
        elif name in TRUTH_NAMES:
            found.append(f"uses {name} (line {node.lineno})")
    return found


@pytest.mark.parametrize("module", sorted(MODULES))
def test_only_the_world_orchestrators_and_comparison_read_the_truth(module):
    if module.startswith(TRUTH_READERS):
        return
    uses = _truth_uses(module)
    assert not uses, (
        f"{module} reads the truth ({'; '.join(uses)}); only {', '.join(TRUTH_READERS)} may: the "
        "researcher side and the design tools work from measurements and explicit priors"
    )


def test_contract_checks_see_a_forbidden_import(tmp_path, monkeypatch):
    """The checks are not vacuous: a researcher module that imports the rig is caught, with its chain."""
    fake = PACKAGE / "researcher" / "measure.py"
    monkeypatch.setitem(MODULES, "vtestbed.researcher._probe", tmp_path / "probe.py")
    (tmp_path / "probe.py").write_text("from .measure import wrench_at_block\nfrom ..world.rig import Rig\n")
    bad = forbidden_reach("vtestbed.researcher._probe")
    assert "vtestbed.researcher._probe -> vtestbed.world.rig" in bad, bad
    assert "vtestbed.researcher._probe -> vtestbed.world.rig -> mujoco" in bad, bad
    (tmp_path / "probe.py").write_text("from ..comparison import read_truth\nk = x.stiffness_true\n")
    assert len(_truth_uses("vtestbed.researcher._probe")) == 3
    assert fake.exists()  # the real module is untouched


def test_researcher_imports_in_a_fresh_interpreter_without_mujoco():
    code = (
        "import sys, vtestbed.researcher, vtestbed.dataset, vtestbed.ply;"
        "print(sorted(m for m in sys.modules if m.split('.')[0] == 'mujoco' or m.startswith('vtestbed.world')))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]", f"importing the researcher side loaded {out.strip()}"
