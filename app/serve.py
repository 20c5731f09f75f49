"""Start the service: ``python -m app.serve [--host H] [--port P] [--workers N]``.

uvicorn with ``--workers N`` runs N processes on one port, and a scrape of ``/metrics`` reaches
whichever of them accepts it: each had counters of its own, so the frames counted went up and
down from scrape to scrape (40 frames over 2 workers read 16, 24, 16, 24 …), which Prometheus
takes for counter resets. With more than one worker this sets ``PROMETHEUS_MULTIPROC_DIR`` to
a directory of its own (emptied first: counts of an earlier run must not add up with these),
where every worker writes its counters and from which ``/metrics`` sums them. A directory set
by the caller is used as it is.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
from pathlib import Path

METRICS_DIR = "PROMETHEUS_MULTIPROC_DIR"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=8000)
    parser.add_argument("--workers", type=int, default=1)
    args, uvicorn_args = parser.parse_known_args(argv)
    if args.workers > 1 and METRICS_DIR not in os.environ:
        # one directory per port: two servers on one host never share (nor empty) it
        metrics = Path(tempfile.gettempdir()) / f"vantage-metrics-{args.port}"
        shutil.rmtree(metrics, ignore_errors=True)
        metrics.mkdir(parents=True)
        os.environ[METRICS_DIR] = str(metrics)
    command = [
        sys.executable,
        "-m",
        "uvicorn",
        "app.main:create_app",
        "--factory",
        "--host",
        args.host,
        "--port",
        str(args.port),
        "--workers",
        str(args.workers),
        *uvicorn_args,
    ]
    os.execv(sys.executable, command)


if __name__ == "__main__":
    main()
