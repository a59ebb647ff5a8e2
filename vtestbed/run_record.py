"""What a run records beside its numbers: the wall time of each phase [s] and the versions of the
packages that computed them (read from the installed metadata, so nothing is imported)."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["VERSIONED", "Timings", "versions"]


@dataclass
class Timings:
    """Wall time per phase [s], for the benchmark and the run summary."""

    physics: float = 0.0
    scan: float = 0.0
    write: float = 0.0
    process: float = 0.0
    identify: float = 0.0
    report: float = 0.0

    def as_dict(self) -> dict:
        return {k: round(v, 4) for k, v in self.__dict__.items()}


VERSIONED = ("numpy", "scipy", "mujoco", "pin", "open3d")


def versions() -> dict[str, str]:
    """The versions that shape a run's numbers (read from the installed metadata, no imports)."""
    import platform
    from importlib import metadata

    from . import __version__

    out = {"vtestbed": __version__, "python": platform.python_version()}
    for name in VERSIONED:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out
