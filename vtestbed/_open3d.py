"""Import open3d on a machine without the system libusb.

open3d 0.20 wheels link against libusb-1.0 at import time and a fresh machine lacks it. The
``libusb-package`` wheel ships the library; loading it with RTLD_GLOBAL first satisfies the
dynamic linker, so ``import open3d`` needs no manual step. Every module that needs open3d
imports it from here.

``import open3d`` also runs ``open3d.visualization``, whose ``draw_plotly`` module imports plotly
and dash (0.5-0.7 s and 40 MiB, more than half of open3d's import time). vtestbed never draws
with open3d, so :func:`_defer_plotly` registers a stand-in for that one module before open3d is
imported: ``open3d.visualization.get_plotly_fig``, ``draw_plotly`` and ``draw_plotly_server``
still work, and load the real module (and plotly, dash) on their first call.
"""

from __future__ import annotations

import ctypes
import importlib.util
import sys
import types

_PLOTLY_MODULE = "open3d.visualization.draw_plotly"
_PLOTLY_NAMES = ("get_plotly_fig", "draw_plotly", "draw_plotly_server")


def _preload_libusb() -> None:
    try:
        ctypes.CDLL("libusb-1.0.so.0", mode=ctypes.RTLD_GLOBAL)
        return
    except OSError:
        pass
    import libusb_package  # the wheel that ships libusb

    path = libusb_package.get_library_path()
    if path is not None:
        ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)


def _real_plotly_module() -> types.ModuleType:
    """The real ``open3d.visualization.draw_plotly``, imported on first use (plotly, dash)."""
    module = sys.modules.get(_PLOTLY_MODULE)
    if module is not None and not getattr(module, "_vtestbed_stand_in", False):
        return module
    package = importlib.util.find_spec("open3d.visualization")
    path = next(iter(package.submodule_search_locations)) + "/draw_plotly.py"
    spec = importlib.util.spec_from_file_location(_PLOTLY_MODULE, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[_PLOTLY_MODULE] = module
    spec.loader.exec_module(module)
    visualization = sys.modules.get("open3d.visualization")
    for name in _PLOTLY_NAMES:  # later calls go straight to the real functions
        if visualization is not None:
            setattr(visualization, name, getattr(module, name))
    return module


def _defer_plotly() -> None:
    """Register the stand-in module (only if open3d is not imported yet: then it is too late)."""
    if "open3d" in sys.modules or _PLOTLY_MODULE in sys.modules:
        return
    stand_in = types.ModuleType(_PLOTLY_MODULE, "stand-in: the real module loads on first use")
    stand_in._vtestbed_stand_in = True

    def forward(name):
        def call(*args, **kwargs):
            return getattr(_real_plotly_module(), name)(*args, **kwargs)

        call.__name__ = call.__qualname__ = name
        return call

    for name in _PLOTLY_NAMES:
        setattr(stand_in, name, forward(name))
    sys.modules[_PLOTLY_MODULE] = stand_in


_preload_libusb()
_defer_plotly()

import open3d  # noqa: E402

open3d.utility.set_verbosity_level(open3d.utility.VerbosityLevel.Error)
# open3d's multi-threaded RANSAC (segment_plane) is not repeatable even with a fixed seed: the
# threads race for the best model. One thread makes the same seed give the same frame; parallel
# speed comes from running trials in separate processes instead.
open3d.utility.set_max_threads(1)

o3d = open3d
__all__ = ["o3d"]
