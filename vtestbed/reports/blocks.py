"""The building blocks of a report section: text, key-value lists, tables, figures, the 3-D view.

A section is a title and a list of blocks; the template (``templates/report.html.j2``) renders
each block by its ``kind``. Numbers stay numbers (:class:`Num`) until the template formats them,
so a test can compare what the page shows with the result files.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from importlib import metadata


@dataclass(frozen=True)
class Num:
    """A number and how to show it (a format spec, a scale and a unit suffix)."""

    value: float | None
    spec: str = ".4g"
    scale: float = 1.0

    def __str__(self) -> str:
        if self.value is None or (isinstance(self.value, float) and not math.isfinite(self.value)):
            return "n/a"
        return format(self.value * self.scale, self.spec)


@dataclass
class Text:
    """Paragraphs of plain text (escaped by the template)."""

    paragraphs: list[str]
    id: str = ""
    kind: str = "text"


@dataclass
class KeyValues:
    """A two-column list: ``[(label, value), ...]``; values are str or :class:`Num`."""

    items: list[tuple[str, object]]
    id: str = ""
    kind: str = "keyvalues"


@dataclass
class Table:
    """A table: column headers and rows of cells (str or :class:`Num`)."""

    columns: list[str]
    rows: list[list]
    id: str = ""
    caption: str = ""
    kind: str = "table"


@dataclass
class Figure:
    """A static figure: a ``data:`` URI (PNG) and its caption."""

    src: str
    caption: str
    id: str
    kind: str = "figure"


@dataclass
class Plot3D:
    """An interactive plotly figure: its JSON text and a caption."""

    figure_json: str
    caption: str
    id: str
    kind: str = "plot3d"


@dataclass
class Section:
    """One section of the page: an anchor id, a title and its blocks."""

    id: str
    title: str
    blocks: list = field(default_factory=list)


VERSION_PACKAGES = ("vtestbed", "numpy", "scipy", "pandas", "mujoco", "pin", "open3d", "matplotlib", "plotly")
# where a result file may record the versions that computed it: {package: version}
VERSION_KEYS = ("versions", "package_versions")


def recorded_versions(data: dict | None) -> tuple[str, dict] | None:
    """``(key, {package: version})`` as the result file records them, or None if it records none."""
    for key in VERSION_KEYS:
        value = (data or {}).get(key)
        if isinstance(value, dict) and value:
            return key, value
    return None


def installed_versions() -> list[tuple[str, str]]:
    """The versions installed now (python and :data:`VERSION_PACKAGES`)."""
    import platform

    out = [("python", platform.python_version())]
    for name in VERSION_PACKAGES:
        try:
            out.append((name, metadata.version(name)))
        except metadata.PackageNotFoundError:
            out.append((name, "not installed"))
    return out


def versions(data: dict | None = None, source: str = "the result file") -> list[tuple[str, object]]:
    """Version rows for a report's details, headed by a row saying where they come from.

    The versions recorded in ``data`` (under a key of :data:`VERSION_KEYS`) are those that
    computed the numbers; without them, the installed versions are shown and labelled as those
    installed when the report was written (the result may have been computed with others).
    """
    found = recorded_versions(data)
    if found is not None:
        key, recorded = found
        head = ("versions", f"recorded in {source} ({key!r}) when the result was computed")
        # the rest (the page's plotting, for one) only as installed now, and labelled so
        now = [(f"{name} (installed when this report was written)", v) for name, v in installed_versions()
               if name not in recorded]  # fmt: skip
        return [head, *((str(k), str(v)) for k, v in recorded.items()), *now]
    head = ("versions", f"installed when this report was written ({source} records none; "
                        "the result may have been computed with others)")  # fmt: skip
    return [head, *installed_versions()]
