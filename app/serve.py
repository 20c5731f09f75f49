"""Start the service: ``python -m app.serve [--host H] [--port P] [--workers N]``.

uvicorn with ``--workers N`` runs N processes on one port, and a scrape of ``/metrics`` reaches
whichever of them accepts it. With more than one worker this sets ``PROMETHEUS_MULTIPROC_DIR``
to a directory of its own (emptied first), where every worker writes its counters and from
which ``/metrics`` sums them. A directory set by the caller is used as it is.

Request deadlines, header limits and slow clients are the reverse proxy's (docs/operations.md,
``deploy/nginx.conf``). Here: uvicorn's graceful shutdown bounded by
``VANTAGE_SHUTDOWN_GRACE_SECONDS``, idle connections kept ``KEEP_ALIVE_S``, the soft limit on
open files lifted to the hard one, and JSON log lines from the start. Other options are
uvicorn's, passed through.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import shutil
import sys
import tempfile
from pathlib import Path

from app.platform.settings import get_settings

METRICS_DIR = "PROMETHEUS_MULTIPROC_DIR"
KEEP_ALIVE_S = "75"
"""How long an idle kept-alive connection stays open [s]: longer than the proxy's or load
balancer's own idle timeout (60 s for nginx's upstreams and AWS's ALB), or they would send on a
connection being closed and answer 502."""


def raise_file_limit() -> int:
    """Lift this process's soft limit on open files to its hard one (as Go's runtime does for
    every server), for it and the workers it starts; return the limit now. Each connection
    takes a file, and under systemd's soft limit of 1,024 a thousand cameras kept connected
    leave none for a request, a frame's pack or the database. The hard limit is the
    operator's (``LimitNOFILE=``, ``ulimit -Hn``)."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    # an unlimited hard limit: Linux's own ceiling (fs.nr_open) by default
    target = 1 << 20 if hard == resource.RLIM_INFINITY else hard
    if soft == resource.RLIM_INFINITY or soft >= target:
        return soft
    try:
        resource.setrlimit(resource.RLIMIT_NOFILE, (target, hard))
    except (ValueError, OSError):  # fs.nr_open set lower than the hard limit
        return soft
    return target


def _log_config(port: int, level: str) -> Path:
    """uvicorn's logging as JSON lines from its start, in the supervising process of several
    workers too, which never runs the application's own set-up (``configure_logging``):
    its lines came as plain text among the JSON ones. A file per port, as uvicorn reads it."""
    config = {
        "version": 1,
        "disable_existing_loggers": False,
        "formatters": {"json": {"()": "app.platform.observability.JsonFormatter"}},
        "handlers": {
            "stderr": {
                "class": "logging.StreamHandler",
                "formatter": "json",
                "stream": "ext://sys.stderr",
            }
        },
        "loggers": {
            "uvicorn": {"handlers": ["stderr"], "level": level.upper(), "propagate": False},
            # vantage.access logs each request, with its id
            "uvicorn.access": {"handlers": [], "level": "WARNING", "propagate": False},
        },
    }
    path = Path(tempfile.gettempdir()) / f"vantage-logging-{port}.json"
    path.write_text(json.dumps(config))
    return path


def _unless_given(option: str, ours: list[str], given: list[str]) -> list[str]:
    """``ours`` (an option and its value), unless the caller gave ``option`` itself."""
    return [] if any(a.split("=")[0] == option for a in given) else ours


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=8000)
    parser.add_argument("--workers", type=int, default=1)
    args, uvicorn_args = parser.parse_known_args(argv)
    raise_file_limit()
    if args.workers > 1 and METRICS_DIR not in os.environ:
        # one directory per port: two servers on one host never share (nor empty) it
        metrics = Path(tempfile.gettempdir()) / f"vantage-metrics-{args.port}"
        shutil.rmtree(metrics, ignore_errors=True)
        metrics.mkdir(parents=True)
        os.environ[METRICS_DIR] = str(metrics)
    settings = get_settings()  # a wrong setting stops here too, before any worker starts
    if settings.log_json and not any(a.split("=")[0] == "--log-config" for a in uvicorn_args):
        log_config = _log_config(args.port, settings.log_level)
        uvicorn_args = ["--log-config", str(log_config), *uvicorn_args]
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
        *_unless_given(
            "--timeout-keep-alive", ["--timeout-keep-alive", KEEP_ALIVE_S], uvicorn_args
        ),
        *_unless_given(
            "--timeout-graceful-shutdown",
            ["--timeout-graceful-shutdown", str(math.ceil(settings.shutdown_grace_seconds))],
            uvicorn_args,
        ),
        *uvicorn_args,
    ]
    os.execv(sys.executable, command)


if __name__ == "__main__":
    main()
