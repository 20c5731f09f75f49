"""Peak memory of a piece of code, measured in an interpreter of its own.

tracemalloc counts the allocations of every thread of the process it runs in: measured inside
the test process, a background thread that outlived an earlier test is counted too (a CI run
saw a 1.5 GB peak for code that takes 10 MB).
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from typing import Any

from tests.factories import ROOT


def traced_peak(setup: str, measured: str) -> tuple[int, Any]:
    """Run ``setup``, then ``measured`` under tracemalloc, in a fresh interpreter; return the
    peak of what ``measured`` allocated [bytes] and the JSON value it left in ``result``."""
    script = "\n".join(
        [
            "import json, tracemalloc",
            textwrap.dedent(setup),
            "tracemalloc.start()",
            textwrap.dedent(measured),
            "peak = tracemalloc.get_traced_memory()[1]",
            "tracemalloc.stop()",
            'print(json.dumps({"peak": peak, "result": result}))',
        ]
    )
    done = subprocess.run(
        [sys.executable, "-c", script],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    answer = json.loads(done.stdout.splitlines()[-1])
    return int(answer["peak"]), answer["result"]
