"""docs/errors.md lists every problem ``code`` the service can answer with, and no other."""

from __future__ import annotations

import re

from tests.factories import ROOT

CODE = re.compile(r"""(?:code=|"code": |code = )"([a-z_]+)\"""")


def test_every_code_is_in_the_reference() -> None:
    used = {
        code for path in (ROOT / "app").rglob("*.py") for code in CODE.findall(path.read_text())
    }
    listed = set(re.findall(r"^\| `([a-z_]+)` \|", (ROOT / "docs/errors.md").read_text(), re.M))
    assert len(used) > 50  # the scan finds the codes at all
    assert used - listed == set(), "codes the reference lacks"
    assert listed - used == set(), "codes the reference names that no longer exist"
