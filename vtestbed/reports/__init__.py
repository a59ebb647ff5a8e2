"""Self-contained HTML reports of a run, a campaign or a diagnosis (``vtestbed report DIR``).

Modules: :mod:`.loader` (which kind of result a folder holds, and loading it), :mod:`.figures`
(static figures as embedded PNG), :mod:`.scene` (the interactive 3-D view of one test),
:mod:`.blocks` (what a section is made of), ``sections_run``, ``sections_campaign`` and
``sections_diagnosis`` (one function per section) and :mod:`.render` (the Jinja2 template).
"""

from __future__ import annotations

from .loader import KINDS, ReportError, ResultFolder, detect_kind, load_result
from .render import REPORT_FILE, build_sections, render, write_report
from .scene import one_test_scene

__all__ = [
    "KINDS",
    "REPORT_FILE",
    "ReportError",
    "ResultFolder",
    "build_sections",
    "detect_kind",
    "load_result",
    "one_test_scene",
    "render",
    "write_report",
]
