"""One registry style for everything chosen by name: drivers, dataset readers, commands, attitude algorithms.

As python-can's ``BACKENDS`` (``{"socketcan": ("can.interfaces.socketcan", "SocketcanBus")}``), a
:class:`Registry` maps a name to ``(module, attribute)`` and imports the module only when that name is first
used: the registering module never imports what it registers (no import circle), and naming one entry imports
that one only (``ins-hil --help`` imports no command, a serial-only gateway never imports python-can). An
attribute that is a table (a ``dict``) is indexed by the entry's name (a module with several entries, e.g.
``ins_hil.nav.onestep.ALGORITHMS``). Third parties add entries with :meth:`Registry.register` (a loaded object
or a ``(module, attribute)`` pair), or, when the registry has an entry-point ``group``, through the Python
entry points of that group (``[project.entry-points."ins_hil.drivers"] my_imu = "my_pkg.imu:MyImuDriver"``).

The lowest layer of the package: it imports nothing of ins_hil.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator, Mapping
from typing import Any, Generic, TypeVar

T = TypeVar("T")

#: where an entry lives: (module, attribute), imported on first use
Where = tuple[str, str]


class Registry(Mapping[str, T], Generic[T]):
    """Name → object, each entry a loaded object or a lazy ``(module, attribute)``, in registration order.

    ``what``: what an entry is, for the one-line error of an unknown name (``unknown driver type 'x' (known:
    ...)``). Iterating gives the names (entry points of ``group`` not included until named); indexing or
    :meth:`get` loads the entry; :meth:`where` tells where a name lives without importing it."""

    def __init__(self, what: str, entries: Mapping[str, Where | T] | None = None, group: str = "") -> None:
        self.what = what
        self.group = group
        self._entries: dict[str, Where | T] = dict(entries or {})

    def register(self, name: str, entry: Where | T) -> None:
        """Add (or replace) ``name``: a loaded object or a ``(module, attribute)`` pair."""
        self._entries[name] = entry

    def copy(self) -> Registry[T]:
        """A registry with the same entries (loaded ones stay loaded, lazy ones lazy)."""
        return Registry(self.what, self._entries, self.group)

    def where(self, name: str) -> Where | None:
        """``(module, attribute)`` of a lazy entry, None for a loaded one; KeyError for an unknown name."""
        e = self._entries[name]
        return e if _lazy(e) else None  # type: ignore[return-value]

    def loaded(self, name: str) -> bool:
        """Whether the entry ``name`` has been imported already."""
        return name in self._entries and not _lazy(self._entries[name])

    def __getitem__(self, name: str) -> T:
        if not isinstance(name, str):  # e.g. a list from a config file: no such entry
            raise KeyError(name)
        if name not in self._entries and self.group and name:
            for ep in entry_points(group=self.group):  # imported here: importlib.metadata is slow to import
                if ep.name == name:
                    self._entries[name] = ep.load()
                    break
        try:
            e = self._entries[name]
        except KeyError:
            raise KeyError(name) from None
        if _lazy(e):
            module, attr = e  # type: ignore[misc]
            obj = getattr(importlib.import_module(module), attr)
            if isinstance(obj, dict):  # a module-level table of several entries
                obj = obj[name]
            self._entries[name] = e = obj
        return e  # type: ignore[return-value]

    def load(self, name: Any) -> T:
        """The entry ``name``; ValueError in one line naming the known ones for an unknown name."""
        try:
            return self[name]
        except KeyError:
            raise ValueError(f"unknown {self.what} {name!r} (known: {', '.join(self._entries)})") from None

    def __iter__(self) -> Iterator[str]:
        return iter(list(self._entries))

    def __len__(self) -> int:
        return len(self._entries)

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and name in self._entries

    def __repr__(self) -> str:
        return f"Registry({self.what!r}, {list(self._entries)})"


def _lazy(e: Any) -> bool:
    return isinstance(e, tuple) and len(e) == 2 and all(isinstance(x, str) for x in e)


def entry_points(group: str) -> Any:
    """The Python entry points of ``group`` (importlib.metadata imported on first use: ``ins-hil --help``)."""
    from importlib.metadata import entry_points as eps

    return eps(group=group)
