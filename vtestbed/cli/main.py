"""The ``vtestbed`` command. Each topic registers its subcommands from its own module."""

from __future__ import annotations

import argparse
import importlib
import sys

from ..errors import VtestbedError

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


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except VtestbedError as exc:
        print(f"vtestbed: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("vtestbed: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
