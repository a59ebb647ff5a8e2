"""Monte Carlo campaigns: many virtual experiments over noise levels, test counts and pose sets.

:func:`load_campaign` reads a scenario file with a ``[campaign]`` table (:mod:`.spec`);
:func:`sweep` runs it on local processes or Dask into a resumable results folder (:mod:`.runner`,
:mod:`.store`; the workers run :mod:`.worker`); :func:`write_report` summarises it
(:mod:`.report`). :func:`prepare` and :func:`trial` (:mod:`.montecarlo`) are one virtual
experiment on fixed physics. Campaigns may read the truth: they compare estimates with it.

The names are loaded on first use: a campaign worker imports this package (to unpickle its
tasks) and must not pay for pandas, pyarrow or matplotlib, which only the parent's bookkeeping
and the reports need.
"""

from importlib import import_module

_EXPORTS = {
    "Campaign": ".spec",
    "Cell": ".spec",
    "PoseSetOptions": ".spec",
    "load_campaign": ".spec",
    "parse_campaign": ".spec",
    "PreparedScenario": ".montecarlo",
    "prepare": ".montecarlo",
    "trial": ".montecarlo",
    "TestPlan": ".posesets",
    "build_plans": ".posesets",
    "write_report": ".report",
    "SweepStats": ".runner",
    "sweep": ".runner",
    "SweepError": ".store",
    "read_results": ".store",
    "results": ".store",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        value = getattr(import_module(_EXPORTS[name], __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))
