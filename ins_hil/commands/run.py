"""`ins-hil run`: the gateway (until the runtime lands: the simulated end-to-end core run)."""

from __future__ import annotations

import argparse

from ins_hil.commands import demo

NAME = "run"
HELP = "run the gateway (default: built-in simulated sensors)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    demo.add_arguments(p)


def run(args: argparse.Namespace) -> int:
    if not hasattr(args, "profile"):
        args.profile = "uav"
    return demo.run(args)
