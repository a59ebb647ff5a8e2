"""The ``vtestbed`` command. Each topic registers its subcommands from its own module.

Only the module of the command asked for is imported (``vtestbed demo`` does not import the
design tools of ``vtestbed poses``: that saved about 1 s and 150 MiB per command); ``--help``, no
command or an unknown one builds the full parser.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import warnings

from ..errors import VtestbedError
from .args import join_negative_lists, show_warning, shown

# Each command and the module whose ``register(subparsers)`` function adds it
# (tests/test_startup.py checks this table against what the modules register).
COMMANDS = {
    "robot": "vtestbed.cli.robot",
    "load": "vtestbed.cli.robot",
    "models": "vtestbed.cli.robot",
    "simulate": "vtestbed.cli.experiment",
    "identify": "vtestbed.cli.experiment",
    "run": "vtestbed.cli.experiment",
    "demo": "vtestbed.cli.experiment",
    "scan": "vtestbed.cli.scan",
    "poses": "vtestbed.cli.poses",
    "sweep": "vtestbed.cli.sweep",
    "effects": "vtestbed.cli.effects",
    "diagnose": "vtestbed.cli.diagnose",
    "report": "vtestbed.cli.report",
    "discover": "vtestbed.cli.discover",
    "dataset": "vtestbed.cli.dataset",
}
COMMAND_MODULES = list(dict.fromkeys(COMMANDS.values()))


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The argument parser: every command, or only ``command``'s module when it is a known one."""
    parser = argparse.ArgumentParser(
        prog="vtestbed", description="A virtual lab for joint-stiffness identification."
    )
    sub = parser.add_subparsers(dest="command", required=True)
    module = COMMANDS.get(command or "")
    for name in [module] if module is not None else COMMAND_MODULES:
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
    command = argv[0] if argv and not argv[0].startswith("-") else None
    args = build_parser(command).parse_args(argv)
    previous, warnings.showwarning = warnings.showwarning, show_warning
    shown.clear()
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
    except RuntimeError as exc:
        # Ctrl-C landing while a threading.Condition releases its lock (a sweep waiting on its
        # worker processes) surfaces as "RuntimeError: release unlocked lock" raised while the
        # KeyboardInterrupt is handled: it is the same interruption, and must end the same way
        if not isinstance(exc.__context__, KeyboardInterrupt):
            raise
        print("vtestbed: interrupted", file=sys.stderr)
        return 130
    finally:
        warnings.showwarning = previous


if __name__ == "__main__":
    sys.exit(main())
