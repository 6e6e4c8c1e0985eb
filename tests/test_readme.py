"""The README's example runs as written (its ```pycon blocks are doctests)."""

from __future__ import annotations

import doctest
import re
from pathlib import Path

README = Path(__file__).resolve().parent.parent / "README.md"


def test_readme_examples_run():
    blocks = re.findall(r"```pycon\n(.*?)```", README.read_text(), flags=re.S)
    assert blocks, "README has no ```pycon example"
    runner = doctest.DocTestRunner(optionflags=doctest.NORMALIZE_WHITESPACE)
    for i, src in enumerate(blocks):
        test = doctest.DocTestParser().get_doctest(src, {}, f"README[{i}]", str(README), 0)
        runner.run(test)
    res = runner.summarize(verbose=False)
    assert res.failed == 0 and res.attempted >= 10


def test_public_api_names():
    import ins_hil

    for name in ("NavCore", "NavConfig", "ImuSample", "GnssFix", "BaroSample", "MagSample", "NavState"):
        assert getattr(ins_hil, name).__name__ == name
    assert "NavCore" in dir(ins_hil)
