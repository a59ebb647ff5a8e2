"""The ``vtestbed`` command line: one module per command group, shared argument helpers."""

from .main import build_parser, main

__all__ = ["build_parser", "main"]
