"""`ins-hil` command line: one subcommand per module in ``ins_hil.commands``.

A command module defines ``NAME``, ``HELP`` (string literals), ``add_arguments(parser)`` and
``run(args) -> int``, and is registered by name in ``ins_hil.commands.COMMANDS`` (one line; the registry
style of the drivers and readers, :mod:`ins_hil.registry`). The command list is read from the registered
modules' source (their ``HELP`` literals, :func:`command_table`) without importing them: ``ins-hil --help``
imports no command, and ``ins-hil CMD ...`` imports only CMD's module, when argparse reaches its name
(:class:`_LazyCommands`).

No command prints a traceback for a bad input: a :class:`~ins_hil.config.ConfigError` or a file that
cannot be read or decoded is one line on stderr and exit status 2; any other exception is one line
plus "(run with --debug for the traceback)" and exit status 1; Ctrl-C is "interrupted", exit status 130, and
SIGTERM "terminated (SIGTERM)", 143, raised like Ctrl-C (:class:`Terminated`; a command that keeps what it
finished says so itself). ``--debug`` (before or after the
command name) or ``INS_HIL_DEBUG=1`` shows the traceback instead.

OpenBLAS runs on one thread (``OPENBLAS_NUM_THREADS=1``) unless the environment sets it.
"""

from __future__ import annotations

import argparse
import ast
import importlib
import importlib.util
import os
import re
import signal
import struct
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

# One BLAS thread unless the user says otherwise: the core's matrices are at most 21 x 21 (below OpenBLAS's
# threading threshold), and its thread pool costs ~0.05 CPU s at numpy's import and competes with the gateway's
# loop on a 2-core host. Set before any command imports numpy.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from ins_hil import __version__, commands


class Command(NamedTuple):
    """A subcommand as listed by ``ins-hil --help``: its name, one-line help and module (not imported)."""

    name: str
    help: str
    module: str


_BODY = re.compile(r"^(?:async\s+def|def|class|@)\b", re.M)  # the first top-level definition ends the header
_RUN = re.compile(r"^(?:async\s+)?def\s+run\s*\(", re.M)


def _literals(path: Path) -> dict[str, Any] | None:
    """The module-level ``NAME``/``HELP`` string literals of a command file (parsed from the source up to
    its first definition, nothing imported) and whether it defines ``run``; None when the file cannot be
    read this way (then only importing it tells)."""
    try:
        text = path.read_text(encoding="utf-8")
        body = _BODY.search(text)
        try:
            tree = ast.parse(text[: body.start()] if body else text, str(path))
        except SyntaxError:  # the header cut inside a string: the whole file
            tree = ast.parse(text, str(path))
    except (OSError, SyntaxError, ValueError):
        return None
    found: dict[str, Any] = {"run": _RUN.search(text) is not None}
    for node in tree.body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
            key = node.targets[0].id
            if key in ("NAME", "HELP"):
                if not (isinstance(node.value, ast.Constant) and isinstance(node.value.value, str)):
                    return None  # computed: only the import tells
                found[key] = node.value.value
    if "NAME" not in found and re.search(r"^NAME\b", text, re.M):
        return None  # NAME set after the first definition
    return found


def command_table() -> dict[str, Command]:
    """Every command of the registry ``ins_hil.commands.COMMANDS`` by name, in name order, its help read from
    its module's source without importing it (a module whose ``NAME``/``HELP`` are not string literals is
    imported to read them)."""
    out: dict[str, Command] = {}
    for name in commands.COMMANDS:
        where = commands.COMMANDS.where(name)
        if where is None:  # registered as a loaded object: its module is imported already
            run = commands.COMMANDS[name]
            mod = importlib.import_module(run.__module__)
            out[name] = Command(name, getattr(mod, "HELP", ""), run.__module__)
            continue
        module = where[0]
        spec = importlib.util.find_spec(module)  # imports the parent package only
        lit = _literals(Path(spec.origin)) if spec is not None and spec.origin else None
        if lit is None:
            mod = importlib.import_module(module)
            out[name] = Command(name, getattr(mod, "HELP", ""), module)
        else:
            out[name] = Command(name, lit.get("HELP", ""), module)
    return dict(sorted(out.items()))


class _Parser(argparse.ArgumentParser):
    """An argument error is one line, ``PROG: error: MESSAGE (PROG --help)``, exit status 2: not argparse's usage
    block first (a dozen lines for ``replay`` or ``soak``, the error last)."""

    def error(self, message: str) -> Any:
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())} (see {self.prog} --help)\n")


class _LazyCommands(argparse._SubParsersAction):
    """The subcommands' action: a command's module is imported, and its arguments added to its parser,
    only when argparse reaches that command's name."""

    modules: dict[str, str]

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:  # fmt: skip
        name = values[0]
        module = self.modules.pop(name, None)
        if module is not None:
            _load(self._name_parser_map[name], module)
        super().__call__(parser, namespace, values, option_string)


def _load(p: argparse.ArgumentParser, module: str) -> None:
    mod = importlib.import_module(module)
    p.description = getattr(mod, "DESCRIPTION", mod.HELP)
    mod.add_arguments(p)
    p.set_defaults(_run=mod.run)


def build_parser() -> argparse.ArgumentParser:
    """The ``ins-hil`` parser: every command listed with its help; a command's own arguments are added
    when it is parsed (its module imported then)."""
    parser = _Parser(
        prog="ins-hil",
        description="Hardware-in-the-loop navigation gateway: strapdown INS + EKF + FDI, "
        "IMU over serial/CAN, GNSS over MAVLink, state out over MAVLink and MQTT.",
    )
    parser.add_argument("--version", action="version", version=f"ins-hil {__version__}")
    parser.add_argument("--debug", action="store_true", help="show the traceback of an error (also INS_HIL_DEBUG=1)")
    common = _Parser(add_help=False)
    common.add_argument(
        "--debug", action="store_true", default=argparse.SUPPRESS, help="show the traceback of an error"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", action=_LazyCommands)
    assert isinstance(sub, _LazyCommands)
    sub.modules = {}
    for c in command_table().values():
        sub.add_parser(c.name, help=c.help, description=c.help, parents=[common])
        sub.modules[c.name] = c.module
    return parser


def _command_parser(parser: argparse.ArgumentParser, name: str | None) -> argparse.ArgumentParser:
    """The parser of the command ``name`` (``parser`` itself when there is none)."""
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            return a.choices.get(name or "", parser)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    debug = os.environ.get("INS_HIL_DEBUG", "") not in ("", "0")
    try:
        args, extra = parser.parse_known_args(argv)
        if extra:  # reported by the command's parser: its name and its --help
            _command_parser(parser, getattr(args, "command", None)).error(f"unrecognized arguments: {' '.join(extra)}")
    except Exception as e:  # the command's module failed to import (e.g. a missing optional dependency)
        if debug or "--debug" in (sys.argv[1:] if argv is None else argv):
            raise
        return report_error("ins-hil", e)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    debug = debug or bool(getattr(args, "debug", False))
    old_term = _term_as_interrupt()
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt as e:  # Ctrl-C / SIGTERM that the command did not handle itself: one line
        if debug:
            raise
        term = isinstance(e, Terminated)
        print(f"\nins-hil {args.command}: {'terminated (SIGTERM)' if term else 'interrupted'}", file=sys.stderr)
        return 143 if term else 130
    except Exception as e:
        if debug:
            raise
        return report_error(f"ins-hil {args.command}", e)
    finally:
        if old_term is not None:
            signal.signal(signal.SIGTERM, old_term)


class Terminated(KeyboardInterrupt):
    """SIGTERM during a command (``timeout``, a service manager): raised like Ctrl-C's KeyboardInterrupt, so what a
    command keeps on Ctrl-C (a batch's finished replays, a soak's cleanup) it keeps on SIGTERM; exit status 143."""


def _on_term(signum: int, frame: Any) -> None:
    raise Terminated()


def _term_as_interrupt() -> Any:
    """SIGTERM raises :class:`Terminated` while a command runs, unless something set a handler already (a command
    may set its own: the gateway stops cleanly, fuzz writes its report). Returns the handler to restore, or None."""
    import threading

    if threading.current_thread() is not threading.main_thread() or signal.getsignal(signal.SIGTERM) != signal.SIG_DFL:
        return None
    return signal.signal(signal.SIGTERM, _on_term)


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
