"""vtestbed: a virtual lab for robot joint-stiffness identification (Gao et al., Appl. Sci. 2023).

The common entry points, loaded on first use (so that ``import vtestbed.researcher`` stays free
of MuJoCo)::

    import vtestbed as vt

    scenario = vt.load_scenario("scenarios/kr60_paper.toml")
    vt.simulate(scenario, "runs/paper/dataset")           # the world writes a dataset
    setup, tests, result = vt.identify_dataset("runs/paper/dataset")  # the researcher's side
    summary = vt.run(scenario, "runs/paper")              # both, then the truth comparison
    trials = vt.sweep("scenarios/kr60_sweep_quick.toml", "runs/quick")  # Monte Carlo

The rooms: :mod:`vtestbed.world` (truth, MuJoCo), :mod:`vtestbed.researcher` (datasets only),
:mod:`vtestbed.design`, :mod:`vtestbed.campaigns`, :mod:`vtestbed.cli`; see docs/architecture.md.
"""

from importlib import import_module

__version__ = "0.2.0"

_EXPORTS = {
    "VtestbedError": "vtestbed.errors",
    "LabSetup": "vtestbed.lab",
    "RobotDescription": "vtestbed.robots",
    "load_robot": "vtestbed.robots",
    "Scenario": "vtestbed.scenario",
    "load_scenario": "vtestbed.scenario",
    "parse_scenario": "vtestbed.scenario",
    "simulate": "vtestbed.experiment",
    "identify_dataset": "vtestbed.dataset_identification",
    "run": "vtestbed.experiment",
    "diagnose": "vtestbed.researcher.discrepancy",
    "discover": "vtestbed.discovery",
    "Campaign": "vtestbed.campaigns",
    "load_campaign": "vtestbed.campaigns",
    "sweep": "vtestbed.campaigns",
}

__all__ = sorted([*_EXPORTS, "__version__"])


def __getattr__(name: str):
    if name in _EXPORTS:
        value = getattr(import_module(_EXPORTS[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'vtestbed' has no attribute {name!r}")


def __dir__():
    return __all__
