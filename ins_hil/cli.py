"""`ins-hil` command line: one subcommand per module in ``ins_hil.commands``.

A command module defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and
``run(args) -> int``; it is found automatically, so adding a command is
adding a file.

No command prints a traceback for a bad input: a :class:`~ins_hil.config.ConfigError` or a file that
cannot be read or decoded is one line on stderr and exit status 2; any other exception is one line
plus "(run with --debug for the traceback)" and exit status 1. ``--debug`` (before or after the
command name) or ``INS_HIL_DEBUG=1`` shows the traceback instead.
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import struct
import sys
from collections.abc import Sequence
from types import ModuleType

from ins_hil import __version__, commands


def _command_modules() -> list[ModuleType]:
    mods = []
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda i: i.name):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"ins_hil.commands.{info.name}")
        if hasattr(mod, "NAME") and hasattr(mod, "run"):
            mods.append(mod)
    return mods


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="ins-hil",
        description="Hardware-in-the-loop navigation gateway: strapdown INS + EKF + FDI, "
        "IMU over serial/CAN, GNSS over MAVLink, state out over MAVLink and MQTT.",
    )
    parser.add_argument("--version", action="version", version=f"ins-hil {__version__}")
    parser.add_argument("--debug", action="store_true", help="show the traceback of an error (also INS_HIL_DEBUG=1)")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument(
        "--debug", action="store_true", default=argparse.SUPPRESS, help="show the traceback of an error"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for mod in _command_modules():
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=getattr(mod, "DESCRIPTION", mod.HELP), parents=[common])
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    debug = bool(getattr(args, "debug", False)) or os.environ.get("INS_HIL_DEBUG", "") not in ("", "0")
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        return 130
    except Exception as e:
        if debug:
            raise
        return report_error(f"ins-hil {args.command}", e)


def _one_line(e: BaseException) -> str:
    return " ".join(str(e).split()) or type(e).__name__


#: exceptions that mean a bad input (a config, a log, a file that cannot be read or decoded): exit status 2
INPUT_ERRORS: tuple[type[BaseException], ...] = (OSError, ValueError, EOFError, struct.error)


def report_error(prog: str, e: BaseException) -> int:
    """One line on stderr for an exception that escaped a command; returns the exit status (2 bad input, 1 other)."""
    from ins_hil.config import ConfigError

    if isinstance(e, ConfigError):
        print(f"{prog}: {_one_line(e)}", file=sys.stderr)
        return 2
    if isinstance(e, OSError) and e.strerror:
        where = f"{e.filename}: " if e.filename else ""
        print(f"{prog}: {where}{e.strerror}", file=sys.stderr)
        return 2
    name = type(e).__name__ if type(e).__name__ != "error" else f"{type(e).__module__}.error"
    print(f"{prog}: {name}: {_one_line(e)} (run with --debug for the traceback)", file=sys.stderr)
    return 2 if isinstance(e, INPUT_ERRORS) else 1


if __name__ == "__main__":
    sys.exit(main())
