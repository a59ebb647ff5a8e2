"""Monte Carlo campaigns: many virtual experiments over noise levels, test counts and pose sets.

:func:`load_campaign` reads a scenario file with a ``[campaign]`` table (:mod:`.spec`);
:func:`sweep` runs it on local processes or Dask into a resumable results folder (:mod:`.runner`,
:mod:`.store`); :func:`write_report` summarises it (:mod:`.report`). :func:`prepare` and
:func:`trial` (:mod:`.montecarlo`) are one virtual experiment on fixed physics. Campaigns may
read the truth: they compare estimates with it.
"""

from .montecarlo import PreparedScenario, prepare, trial
from .posesets import TestPlan, build_plans
from .report import write_report
from .runner import SweepStats, sweep
from .spec import Campaign, Cell, PoseSetOptions, load_campaign, parse_campaign
from .store import SweepError, read_results, results

__all__ = [
    "Campaign",
    "Cell",
    "PoseSetOptions",
    "PreparedScenario",
    "SweepError",
    "SweepStats",
    "TestPlan",
    "build_plans",
    "load_campaign",
    "parse_campaign",
    "prepare",
    "read_results",
    "results",
    "sweep",
    "trial",
    "write_report",
]
