"""Start the service: ``python -m app.serve [--host H] [--port P] [--workers N]``.

uvicorn with ``--workers N`` runs N processes on one port, and a scrape of ``/metrics`` reaches
whichever of them accepts it: each had counters of its own, so the frames counted went up and
down from scrape to scrape (40 frames over 2 workers read 16, 24, 16, 24 …), which Prometheus
takes for counter resets. With more than one worker this sets ``PROMETHEUS_MULTIPROC_DIR`` to
a directory of its own (emptied first: counts of an earlier run must not add up with these),
where every worker writes its counters and from which ``/metrics`` sums them. A directory set
by the caller is used as it is.

Connections are served by ``app.protocol`` (unless ``--http`` names another), which bounds
what uvicorn's own did not: how long a client may take to send its request or to read the
answer, its headers' size, the requests it may pipeline, and how long a stop (SIGTERM) waits
for a body still arriving (``VANTAGE_SHUTDOWN_GRACE_SECONDS``). uvicorn's own graceful
shutdown, which waited for every request however long it took, is bounded ``BACKSTOP_S``
later, for what no client holds: a request still being answered is then cancelled. The
process lifts its soft limit on open files to the hard one first, and keeps idle connections
``KEEP_ALIVE_S`` open unless ``--timeout-keep-alive`` says otherwise. Other options are
uvicorn's.
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

from app import protocol
from app.platform.settings import get_settings

METRICS_DIR = "PROMETHEUS_MULTIPROC_DIR"
HTTP = ["--http", "app.protocol:DeadlineProtocol"]
"""uvicorn's protocol, with bounds on what clients send (``app.protocol``)."""
BACKSTOP_S = 10
"""How much longer than the grace a stop waits for requests still being answered [s]: each
has a bound of its own by then (the upload's ``VANTAGE_UPLOAD_TIMEOUT_SECONDS``, a statement's
timeout), this one is for whatever has not."""
KEEP_ALIVE_S = "75"
"""How long an idle kept-alive connection stays open [s] (nginx's default), longer than the
load balancers' (60 s on AWS's ALB and nginx's upstreams). uvicorn's 5 s closed connections a
balancer was about to reuse: measured, of 12 requests sent on a connection idle ~5 s, 4 found
it closed (a 502 from a balancer). A balancer with a longer idle timeout needs this raised."""


def raise_file_limit() -> int:
    """Lift this process's soft limit on open files to its hard one (as Go's runtime does for
    every server), for it and the workers it starts; return the limit now. Each connection
    takes a file: under systemd's soft limit of 1,024 a thousand cameras kept connected left
    none for a request, a frame's pack or the database (measured: every new connection reset
    at once). The hard limit is the operator's (``LimitNOFILE=``, ``ulimit -Hn``)."""
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
    grace = protocol.deadlines().grace  # a wrong value stops here, with its name
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
        *_unless_given("--http", HTTP, uvicorn_args),
        *_unless_given(
            "--timeout-keep-alive", ["--timeout-keep-alive", KEEP_ALIVE_S], uvicorn_args
        ),
        *_unless_given(
            "--timeout-graceful-shutdown",
            ["--timeout-graceful-shutdown", str(math.ceil(grace) + BACKSTOP_S)],
            uvicorn_args,
        ),
        *uvicorn_args,
    ]
    os.execv(sys.executable, command)


if __name__ == "__main__":
    main()
