"""A headless Chromium for checking reports: Debian's ``/usr/bin/chromium`` driven by Playwright.

Used by the browser tests, ``benchmarks/bench_report.py`` and the documentation's screenshots.
Playwright is launched on the system's Chromium (``executable_path``), never on a browser build
of its own (``playwright install`` downloads one, which this project's machines cannot fetch).
On a fresh machine where Chromium is missing, :func:`ensure_chromium` installs Debian's package
when it runs as root, and otherwise says how to get it.
"""

from __future__ import annotations

import fcntl
import os
import shutil
import subprocess
import tempfile
from contextlib import contextmanager
from pathlib import Path

CHROMIUM = Path("/usr/bin/chromium")
# One installer at a time (the test processes of ``pytest -n 2``, two reports at once): apt-get's
# own lock would fail the second instead of letting it wait for the first.
INSTALL_LOCK = Path(tempfile.gettempdir()) / "vtestbed-chromium-install.lock"
# The machine's Chromium needs these headless: no sandbox (root, containers), no GPU, and none of
# its background traffic, which would both slow the start and defeat the offline check; and no
# /dev/shm for its shared memory (a container's is often 64 MB, too small: tabs crash).
FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-dev-shm-usage",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
)


class BrowserUnavailable(RuntimeError):
    """Chromium or Playwright is missing and cannot be installed here."""


def ensure_chromium(path: Path = CHROMIUM) -> Path:
    """``path`` to Chromium, installing Debian's ``chromium`` package first if it is missing.

    Raises
    ------
    BrowserUnavailable
        Chromium is missing and this process is not root, or the installation failed.
    """
    if path.is_file():
        return path
    if os.geteuid() != 0:
        raise BrowserUnavailable(
            f"{path} is missing and this process is not root: install it with "
            "'sudo apt-get install -y chromium' (the report's browser tests need Debian's Chromium)"
        )
    with INSTALL_LOCK.open("a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if not path.is_file():  # another process may have installed it while this one waited
            _install_chromium(path)
    return path


def _install_chromium(path: Path) -> None:
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    install = ["apt-get", "install", "-y", "-q", "chromium"]
    try:
        if subprocess.run(install, env=env, capture_output=True).returncode != 0:
            # a fresh machine has no package lists yet
            subprocess.run(["apt-get", "update", "-q"], env=env, capture_output=True)
            done = subprocess.run(install, env=env, capture_output=True, text=True)
            if done.returncode != 0:
                raise BrowserUnavailable(
                    f"'apt-get install -y chromium' failed: {done.stderr.strip()[-400:]}"
                )
    except OSError as exc:  # no apt-get (not Debian), or it cannot be run
        raise BrowserUnavailable(
            f"{path} is missing and Debian's chromium package cannot be installed here ({exc}); "
            "install Chromium at that path by other means"
        ) from None
    if not path.is_file():
        raise BrowserUnavailable(f"the chromium package is installed but {path} is not there")


@contextmanager
def chromium(path: Path = CHROMIUM):
    """A Playwright ``Browser`` on the system's Chromium, with a fresh profile; closed on exit."""
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        raise BrowserUnavailable(
            "the Python package 'playwright' is missing: pip install -e '.[test]'"
        ) from None
    exe = ensure_chromium(path)
    profile = tempfile.mkdtemp(prefix="vtestbed-chromium-")
    try:
        with sync_playwright() as pw:
            # a persistent context is the way to give Chromium its own --user-data-dir
            context = pw.chromium.launch_persistent_context(
                profile, executable_path=str(exe), headless=True, args=list(FLAGS[1:]),
                viewport={"width": 1400, "height": 900},
            )  # fmt: skip
            try:
                yield context
            finally:
                context.close()
    finally:
        shutil.rmtree(profile, ignore_errors=True)


def block_network(context) -> list[str]:
    """Abort every http(s) request of ``context``; returns the list the aborted URLs are added to."""
    aborted: list[str] = []

    def _abort(route):
        aborted.append(route.request.url)
        route.abort()

    context.route("http://*/**", _abort)
    context.route("https://*/**", _abort)
    return aborted


def open_report(context, path: str | Path, timeout_ms: float = 30_000):
    """Open a report from ``file://`` in a new page and wait until its figures are drawn.

    Returns ``(page, console_errors, load_seconds)``: the page, the console's error messages and
    page errors, and the time from navigation to the page's ready mark.
    """
    import time

    page = context.new_page()
    errors: list[str] = []
    page.on("console", lambda msg: errors.append(msg.text) if msg.type == "error" else None)
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    t0 = time.perf_counter()
    page.goto(Path(path).resolve().as_uri(), wait_until="load", timeout=timeout_ms)
    page.wait_for_function("document.body.dataset.ready === '1'", timeout=timeout_ms)
    return page, errors, time.perf_counter() - t0


def draw_3d(page, timeout_ms: float = 30_000) -> float:
    """Scroll every interactive figure of ``page`` into view and wait until each is drawn.

    Returns the seconds it took (the figures are drawn lazily, when they come into view).
    """
    import time

    t0 = time.perf_counter()
    for node in page.locator("div.plot3d").all():
        node.scroll_into_view_if_needed(timeout=timeout_ms)
        node.locator("xpath=.").and_(page.locator("[data-drawn='1']")).wait_for(timeout=timeout_ms)
    return time.perf_counter() - t0
