"""The ``ins-hil`` subcommands, one module each (``NAME``, ``HELP`` string literals, ``add_arguments(parser)``,
``run(args) -> int``), registered by name in :data:`COMMANDS` (an :class:`ins_hil.registry.Registry`:
name → (module, ``run``), imported only when that command runs). ``ins-hil --help`` reads each registered
module's ``HELP`` from its source, importing none. Adding a command: its module plus one line here (or
``COMMANDS.register(name, (module, "run"))`` from another package)."""

from __future__ import annotations

from typing import Any

from ins_hil.registry import Registry

#: command name → (module, its ``run``)
COMMANDS: Registry[Any] = Registry(
    "command",
    {
        "bench-core": ("ins_hil.commands.bench_core", "run"),
        "bench-drivers": ("ins_hil.commands.bench_drivers", "run"),
        "bench-fdi": ("ins_hil.commands.bench_fdi", "run"),
        "calibrate": ("ins_hil.commands.calibrate", "run"),
        "config": ("ins_hil.commands.config", "run"),
        "demo": ("ins_hil.commands.demo", "run"),
        "fuzz": ("ins_hil.commands.fuzz", "run"),
        "keygen": ("ins_hil.commands.keygen", "run"),
        "replay": ("ins_hil.commands.replay", "run"),
        "reproduce": ("ins_hil.commands.reproduce", "run"),
        "run": ("ins_hil.commands.run", "run"),
        "soak": ("ins_hil.commands.soak", "run"),
    },
)
