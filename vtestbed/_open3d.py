"""Import open3d on a machine without the system libusb.

open3d 0.20 wheels link against libusb-1.0 at import time and a fresh machine lacks it. The
``libusb-package`` wheel ships the library; loading it with RTLD_GLOBAL first satisfies the
dynamic linker, so ``import open3d`` needs no manual step. Every module that needs open3d
imports it from here.
"""

from __future__ import annotations

import ctypes


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


_preload_libusb()

import open3d  # noqa: E402

open3d.utility.set_verbosity_level(open3d.utility.VerbosityLevel.Error)
# open3d's multi-threaded RANSAC (segment_plane) is not repeatable even with a fixed seed: the
# threads race for the best model. One thread makes the same seed give the same frame; parallel
# speed comes from running trials in separate processes instead.
open3d.utility.set_max_threads(1)

o3d = open3d
__all__ = ["o3d"]
