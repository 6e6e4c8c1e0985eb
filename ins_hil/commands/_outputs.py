"""Up-front checks of a command's output paths (``--out DIR``, ``--output FILE``, ...): a path that cannot be
written is refused in one line naming the flag and the path before any work starts, not after a long run.

Nothing is left behind: a folder or file that does not exist yet is created and removed again (permission bits
and ``os.access`` do not tell everything: a read-only or virtual file system, root's rights), so the command
creates it when it writes. Raises :class:`OutputPathError`, a
:class:`~ins_hil.settings.ConfigError`: ``ins-hil`` prints it as one line, exit status 2.
"""

from __future__ import annotations

import os
from pathlib import Path

from ins_hil.settings import ConfigError

#: this checkout's docs/ folder: where the report commands (bench-*, reproduce, calibrate bench, fuzz) write their
#: generated pages by default, from whatever folder they are run
DOCS = Path(__file__).resolve().parents[2] / "docs"


class OutputPathError(ConfigError):
    """An output path that cannot be written (one line: the flag, the path, why)."""


def _refused(flag: str, path: Path, why: str) -> OutputPathError:
    return OutputPathError(f"{flag} {path}: cannot write: {why}" if flag else f"{path}: cannot write: {why}")


def _ancestor(path: Path) -> Path:
    """The nearest existing ancestor of ``path`` (``.`` for a relative path whose first part does not exist)."""
    a = path.parent
    while not a.exists() and a != a.parent:
        a = a.parent
    return a


def _check_parent(path: Path, flag: str) -> None:
    a = _ancestor(path)
    if not a.is_dir():
        raise _refused(flag, path, f"{a} is a file, not a folder")
    if not os.access(a, os.W_OK | os.X_OK):
        raise _refused(flag, path, f"{a} is not writable")


def _probe(path: Path, flag: str, folder: bool) -> None:
    """Create ``path`` (a folder, or an empty file) and the folders above it that are missing, then remove what
    was created: _refused naming the OS's reason when that fails."""
    made: list[Path] = []
    try:
        for d in reversed([path, *path.parents] if folder else list(path.parents)):
            if not d.exists():
                d.mkdir()
                made.append(d)
        if not folder:
            os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644))
            made.append(path)
    except OSError as e:
        raise _refused(flag, path, e.strerror or str(e)) from None
    finally:
        for d in reversed(made):
            try:
                d.rmdir() if d.is_dir() else d.unlink()
            except OSError:
                pass


def out_dir(path: str | os.PathLike[str], flag: str = "--out") -> Path:
    """``path`` as an output folder: it is one (writable) or can be created. OutputPathError (one line) when it is
    a file, lies under a file, or cannot be created there. Leaves nothing behind; returns ``Path(path)``."""
    p = Path(path)
    if str(path) == "":
        raise OutputPathError(f"{flag}: an empty path")
    if p.exists() or p.is_symlink():
        if not p.is_dir():
            raise _refused(flag, p, "it exists and is not a folder")
        if not os.access(p, os.W_OK | os.X_OK):
            raise _refused(flag, p, "the folder is not writable")
        return p
    _check_parent(p, flag)
    _probe(p, flag, folder=True)
    return p


def out_file(path: str | os.PathLike[str], flag: str = "--out") -> Path:
    """``path`` as an output file: it is a writable file or can be created (its folders too). OutputPathError
    (one line) when it is a folder, lies under a file, or cannot be written. Leaves nothing behind; returns
    ``Path(path)``."""
    p = Path(path)
    if str(path) == "":
        raise OutputPathError(f"{flag}: an empty path")
    if p.is_dir():
        raise _refused(flag, p, "it is a folder, not a file")
    if p.exists():
        if not os.access(p, os.W_OK):
            raise _refused(flag, p, "the file is not writable")
        return p
    _check_parent(p, flag)
    _probe(p, flag, folder=False)
    return p
