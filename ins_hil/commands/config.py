"""`ins-hil config`: validate a configuration file, or regenerate docs/configuration.md from the schema."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

NAME = "config"
HELP = "validate a configuration file (--check FILE) or regenerate docs/configuration.md (--docs)"
DESCRIPTION = (
    "Validate configuration files the way `ins-hil run --config` does before it starts anything (every key "
    "typed and ranged, then the pipeline, endpoints and drivers built without opening a device): prints 'ok' "
    "or the one-line error (exit status 2). --docs writes docs/configuration.md from the keys' field metadata "
    "(ins_hil/settings.py, collected by ins_hil/config_schema.py)."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--check", metavar="TOML", nargs="+", type=Path, help="configuration file(s) to validate")
    p.add_argument("--docs", nargs="?", const="", metavar="PATH",
                   help="write the key reference (default: docs/configuration.md)")  # fmt: skip


def run(args: argparse.Namespace) -> int:
    from ins_hil import config_schema
    from ins_hil.commands._inputs import HINTS, config_kind
    from ins_hil.config import ConfigError, load

    if args.check is None and args.docs is None:
        print("ins-hil config: give --check FILE or --docs", file=sys.stderr)
        return 2
    if args.docs:
        from ins_hil.commands._outputs import out_file

        out_file(args.docs, "--docs")
    status = 0
    for path in args.check or ():
        try:
            load(path)
        except ConfigError as e:
            kind = config_kind(path)
            hint = f" ({HINTS[kind]})" if kind == "dataset" else ""
            print(f"ins-hil config: {e}{hint}", file=sys.stderr)
            status = 2
        else:
            print(f"{path}: ok")
    if args.docs is not None:
        out = config_schema.write_docs(Path(args.docs) if args.docs else config_schema.DOCS)
        print(f"wrote {out}")
    return status
