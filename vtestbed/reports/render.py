"""Rendering: a result folder's sections through the Jinja2 template into one self-contained page.

The page embeds everything: PNG figures as ``data:`` URIs, the 3-D view as plotly JSON and
plotly.js itself (from the installed plotly package, never a CDN), so it opens offline from a
file. Sections are functions ``section(folder) -> Section | None`` listed per kind in
:data:`SECTIONS` (``None``: nothing to show for this folder); a new section is one function
added to its list.
"""

from __future__ import annotations

from pathlib import Path

from markupsafe import Markup

from ..errors import VtestbedError
from ..files import write_atomic
from . import sections_campaign, sections_diagnosis, sections_discovery, sections_run
from .blocks import Num, Section
from .loader import CAMPAIGN_FILE, DIAGNOSIS_FILE, DISCOVERY_FILE, ReportError, ResultFolder, load_result

REPORT_FILE = "report.html"

SECTIONS = {
    "run": sections_run.SECTIONS,
    "campaign": sections_campaign.SECTIONS,
    "diagnosis": sections_diagnosis.SECTIONS,
    "discovery": sections_discovery.SECTIONS,
}
TITLES = {"run": "Run report", "campaign": "Campaign report", "diagnosis": "Diagnosis report",
          "discovery": "Discovery report"}  # fmt: skip
# the file each kind's sections read beyond its checked top-level fields, and the command that writes it
SOURCES = {"campaign": (CAMPAIGN_FILE, "sweep"), "diagnosis": (DIAGNOSIS_FILE, "diagnose --out"),
           "discovery": (DISCOVERY_FILE, "discover --out")}  # fmt: skip


def _script_json(text: str) -> Markup:
    """JSON text made safe inside a <script> element: no '</' can close it early."""
    return Markup(text.replace("</", "<\\/"))


def environment():
    """The Jinja2 environment over the package's templates (autoescaping on)."""
    from jinja2 import Environment, PackageLoader, StrictUndefined, select_autoescape

    env = Environment(
        loader=PackageLoader("vtestbed.reports", "templates"),
        autoescape=select_autoescape(["html", "j2"]),
        undefined=StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
    )
    env.tests["num"] = lambda value: isinstance(value, Num)
    env.filters["script_json"] = _script_json
    return env


def build_sections(folder: ResultFolder) -> list[Section]:
    """The sections of ``folder``'s report, in order (those with nothing to show left out)."""
    return [s for s in (f(folder) for f in SECTIONS[folder.kind]) if s is not None]


def render(folder: ResultFolder) -> str:
    """The HTML text of ``folder``'s report."""
    from importlib import metadata

    sections = build_sections(folder)
    has_plotly = any(b.kind == "plot3d" for s in sections for b in s.blocks)
    plotly_js = ""
    if has_plotly:
        from plotly.offline import get_plotlyjs

        plotly_js = get_plotlyjs()
    name = folder.data.get("scenario") or Path(folder.data.get("dataset", folder.root)).name
    return (
        environment()
        .get_template("report.html.j2")
        .render(
            title=f"{TITLES[folder.kind]}: {name}",
            subtitle=f"vtestbed {folder.kind} report of {folder.root}",
            kind=folder.kind,
            version=metadata.version("vtestbed"),
            source=str(folder.root),
            sections=sections,
            has_plotly=has_plotly,
            plotly_js=Markup(plotly_js),
        )
    )


def write_report(root: str | Path, out: str | Path | None = None) -> Path:
    """Write the report of the result folder ``root`` to ``out`` (default ``root/report.html``).

    Raises
    ------
    ReportError
        ``root`` holds no result (the message lists the files looked for) or a malformed one.
    """
    folder = load_result(root)
    out = Path(root) / REPORT_FILE if out is None else Path(out)
    try:
        html = render(folder)
    except VtestbedError:  # the dataset's own errors (the scene reads it): they name their files
        raise
    except (KeyError, TypeError, AttributeError, IndexError, ValueError) as exc:
        if folder.kind == "run":  # check_run read every field the run sections use: a defect of ours
            raise
        # a campaign's, diagnosis's or discovery's file is checked to its top-level fields only; what
        # lies deeper was written by `vtestbed sweep` / `diagnose` / `discover`: a wrong shape there
        # is an edited file
        name, command = SOURCES[folder.kind]
        raise ReportError(
            f"{folder.root / name}: a field the {folder.kind} report reads is missing or of the wrong type "
            f"({type(exc).__name__}: {exc}); write the file again with 'vtestbed {command}'"
        ) from None
    out.parent.mkdir(parents=True, exist_ok=True)  # `report --out` checked that it may be created
    write_atomic(out, lambda tmp: tmp.write_text(html, encoding="utf-8"))  # plotly.js is not ASCII
    return out
