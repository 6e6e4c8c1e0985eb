"""``ins-hil keygen``: a path it cannot write is one line before a secret is made; a failed ``--force`` leaves no
copy of the new secret behind."""

from __future__ import annotations

from pathlib import Path

import pytest

from ins_hil.cli import main
from ins_hil.commands.keygen import write_key_file


@pytest.mark.parametrize(
    "name, says",
    [
        ("folder", "{p}: cannot write: it is a folder, not a file"),
        ("file/k.key", "{p}: cannot write: {tmp}/file is a file, not a folder"),
        ("none/sub/k.key", "{p}: no folder {tmp}/none/sub (create it first)"),
    ],
)
@pytest.mark.parametrize("force", [False, True])
def test_keygen_refuses_a_path_it_cannot_write(
    name: str, says: str, force: bool, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "folder").mkdir()
    (tmp_path / "file").write_text("x")
    before = sorted(p.name for p in tmp_path.iterdir())
    p = tmp_path / name
    rc = main(["keygen", str(p), *(["--force"] if force else [])])
    err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert rc == 2 and err == ["ins-hil keygen: " + says.format(p=p, tmp=tmp_path)]
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # no folder.tmp with the secret in it


def test_a_failed_replace_leaves_no_copy_of_the_secret(tmp_path: Path) -> None:
    (tmp_path / "k.key").mkdir()  # os.replace of a file onto a folder fails
    with pytest.raises(OSError):
        write_key_file(tmp_path / "k.key", "secret", force=True)
    assert [p.name for p in tmp_path.iterdir()] == ["k.key"]
