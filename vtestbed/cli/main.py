"""The ``vtestbed`` command. Each topic registers its subcommands from its own module."""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from ..errors import VtestbedError
from .args import join_negative_lists

# Modules with a ``register(subparsers)`` function; each adds its own subcommands.
COMMAND_MODULES = [
    "vtestbed.cli.robot",
    "vtestbed.cli.experiment",
    "vtestbed.cli.scan",
    "vtestbed.cli.poses",
    "vtestbed.cli.sweep",
    "vtestbed.cli.effects",
    "vtestbed.cli.diagnose",
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="vtestbed", description="A virtual lab for joint-stiffness identification."
    )
    sub = parser.add_subparsers(dest="command", required=True)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def _silence_stdout() -> None:
    """After a closed pipe (``vtestbed identify DIR | head``): send the rest of stdout, including
    the interpreter's final flush, to devnull, so that nothing more is printed."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):  # stdout is not a real file (captured in tests)
        pass


def main(argv: list[str] | None = None) -> int:
    argv = join_negative_lists(sys.argv[1:] if argv is None else list(argv))
    args = build_parser().parse_args(argv)
    try:
        code = int(args.func(args) or 0)
        sys.stdout.flush()  # a closed pipe shows here, not at the interpreter's exit
        return code
    except BrokenPipeError:  # the reader of our stdout stopped reading: not an error
        _silence_stdout()
        return 0
    except VtestbedError as exc:
        print(f"vtestbed: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # the file system refused (disk full, permissions): no traceback
        print(f"vtestbed: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("vtestbed: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
