"""``vantage``: what operators do in bulk, against a running service over HTTP.

The service's address and a token come from ``VANTAGE_URL`` (default http://127.0.0.1:8000) and
``VANTAGE_TOKEN`` (the admin token; ``replay`` takes the camera's own with ``--camera-token``).
Every command has ``--help``. An answer the service refuses is printed with its reason and the
command exits with status 1; nothing is retried silently.

    vantage cameras import cameras.csv --tokens-out tokens.csv
    vantage panels import panels.csv
    vantage baseline PANEL_ID photos/clean/
    vantage fleet photos/               # sub-folders clean, dust, bird_drop, snow
    vantage air-calibrate skies/ --labels pm25.csv --method regression --applies-to cam-1
    vantage export readings readings.csv --camera-id cam-1 --since 2026-05-01T00:00:00Z
    vantage export panel-history PANEL_ID history.csv --bucket day
    vantage replay CAMERA_ID frames/ --camera-token vc_… --every 1
    vantage replay CAMERA_ID archive/ --camera-token vc_… --time-from-name %Y%m%d-%H%M \
        --timezone Europe/Rome
    vantage replay CAMERA_ID last-year/ --backfill --time-from-name %Y%m%d-%H%M
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import hashlib
import json
import os
import time
from collections.abc import Iterator, Sequence
from datetime import datetime
from pathlib import Path
from typing import Any
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

from rich.progress import Progress

from app.cli import common, energy, stations
from app.cli.common import Failed, Service, err


def import_cameras(service: Service, args: argparse.Namespace) -> None:
    """Register cameras from a CSV: id, kind, then optional name, lat, lon, panel_id, roi (JSON),
    source_url, every_seconds, username, password. The new tokens (shown once) go to
    ``--tokens-out``."""
    rows = common.rows(args.csv)
    tokens = []
    with Progress(console=err) as progress:
        task = progress.add_task("cameras", total=len(rows))
        for i, row in enumerate(rows, start=2):
            if not row.get("id") or not row.get("kind"):
                raise Failed(f"row {i}: id and kind are needed")
            body: dict[str, Any] = {"id": row["id"], "kind": row["kind"]}
            for name in ("name", "panel_id"):
                if row.get(name):
                    body[name] = row[name]
            for name in ("lat", "lon"):
                if (v := common.number(row.get(name, ""), name, i)) is not None:
                    body[name] = v
            if row.get("roi"):
                try:
                    body["roi"] = json.loads(row["roi"])
                except ValueError:
                    raise Failed(f"row {i}: roi must be JSON, as [0, 0, 640, 300]") from None
            if row.get("source_url"):
                every = common.number(row.get("every_seconds", ""), "every_seconds", i)
                body["source"] = {"url": row["source_url"], "every_seconds": int(every or 60)}
                for name in ("username", "password"):
                    if row.get(name):
                        body["source"][name] = row[name]
            created = service.call("POST", "/cameras", json=body).json()
            tokens.append({"id": created["id"], "token": created["token"]})
            progress.advance(task)
    if args.tokens_out:
        with args.tokens_out.open("w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=["id", "token"], lineterminator="\n")
            w.writeheader()
            w.writerows(tokens)
        err.print(f"{len(tokens)} cameras registered; their tokens are in {args.tokens_out}")
    else:
        err.print(f"{len(tokens)} cameras registered; their tokens (shown once):")
        for t in tokens:
            print(f"{t['id']},{t['token']}")


def import_panels(service: Service, args: argparse.Namespace) -> None:
    """Register panels from a CSV: id, then optional name, lat, lon, and the rating pvlib
    models expected energy from: kwp, tilt, azimuth."""
    rows = common.rows(args.csv)
    with Progress(console=err) as progress:
        task = progress.add_task("panels", total=len(rows))
        for i, row in enumerate(rows, start=2):
            if not row.get("id"):
                raise Failed(f"row {i}: id is needed")
            body: dict[str, Any] = {"id": row["id"]}
            if row.get("name"):
                body["name"] = row["name"]
            for name in ("lat", "lon", "kwp", "tilt", "azimuth"):
                if (v := common.number(row.get(name, ""), name, i)) is not None:
                    body[name] = v
            service.call("POST", "/panels", json=body)
            progress.advance(task)
    err.print(f"{len(rows)} panels registered")


def _files(paths: Sequence[Path], what: str) -> list[tuple[str, tuple[str, bytes, str]]]:
    """The images read (with a progress bar), as multipart ``files``."""
    out = []
    seen: dict[str, Path] = {}
    with Progress(console=err) as progress:
        task = progress.add_task(f"reading {what}", total=len(paths))
        for p in paths:
            data = p.read_bytes()
            first = seen.setdefault(hashlib.sha256(data).hexdigest(), p)
            if first != p:
                raise Failed(f"{first} and {p} are the same photo: keep one (a copy weighs twice)")
            kind = (
                "image/jpeg"
                if p.suffix.lower() in (".jpg", ".jpeg")
                else "image/" + p.suffix.lower().lstrip(".")
            )
            out.append(("files", (p.name, data, kind)))
            progress.advance(task)
    return out


def _labelled(
    folder: Path, labels: Path | None, column: str, groups: str | None
) -> tuple[list[Path], list[str], list[str] | None]:
    """The folder's images to send, each one's label (``column`` of the ``labels`` CSV, or its
    sub-folder's name) and, with ``groups`` (a column of that CSV), each one's group."""
    if groups and labels is None:
        raise Failed("--groups names a column of the --labels CSV: give --labels")
    columns = [column, *([groups] if groups else [])]
    paths, values = _labels(folder, common.images(folder), labels, *columns)
    return paths, values[0], values[1] if groups else None


def _labels(
    folder: Path, paths: list[Path], labels: Path | None, *columns: str
) -> tuple[list[Path], list[list[str]]]:
    """The images to send and, for each of ``columns``, each image's value: from ``labels`` (a
    CSV of ``file`` and those columns, file relative to the folder or a bare name), which
    chooses the images (the folder's others are left out, and the user told how many); else
    every image, its one value the name of its sub-folder."""
    if labels is None:
        for p in paths:
            if p.parent == folder:
                raise Failed(
                    f"{p.name} is not in a sub-folder named by its label (or give --labels)"
                )
        return paths, [[p.parent.name for p in paths]]
    rows = common.rows(labels)
    if not rows:
        raise Failed(f"{labels} has no rows")
    for column in ("file", *columns):
        if column not in rows[0]:
            raise Failed(f"{labels} has no column {column}")
    table = {r["file"]: r for r in rows}
    kept, chosen = [], []
    by_name: dict[str, list[Path]] = {}
    for p in paths:
        rel = p.relative_to(folder).as_posix()
        row = table.get(rel, table.get(p.name))
        if row is not None:
            kept.append(p)
            chosen.append(row)
            if rel not in table:
                by_name.setdefault(p.name, []).append(p)
    if twice := {n: ps for n, ps in by_name.items() if len(ps) > 1}:
        name, found = next(iter(twice.items()))
        raise Failed(
            f"{labels} names {name} bare, and {folder} holds it "
            f"{len(found)} times: {', '.join(q.relative_to(folder).as_posix() for q in found)}"
            " (name it by its path in the folder, or keep one)"
        )
    named = {row["file"] for row in chosen}
    if missing := [f for f in table if f not in named]:
        raise Failed(
            f"{labels} names {len(missing)} files not in {folder}: {', '.join(missing[:3])}"
            + (" …" if len(missing) > 3 else "")
        )
    if left := len(paths) - len(kept):
        err.print(f"{left} of the {len(paths)} images in {folder} are not in {labels}: left out")
    for row in chosen:
        for column in columns:
            if not row[column]:
                raise Failed(f"{row['file']} has no {column} in {labels}")
    return kept, [[row[column] for row in chosen] for column in columns]


def baseline(service: Service, args: argparse.Namespace) -> None:
    """A panel's clean baseline from a folder of clean photos."""
    paths = common.images(args.folder)
    params = {"camera_id": args.camera_id} if args.camera_id else {}
    r = service.call(
        "POST", f"/panels/{args.panel_id}/baseline", files=_files(paths, "photos"), params=params
    )
    body = r.json()
    common.warn(body)
    common.say(
        args, f"baseline {body.get('id')} of panel {args.panel_id} from {len(paths)} photos", body
    )


def fleet(service: Service, args: argparse.Namespace) -> None:
    """The fleet model from labelled photos (clean, dust, bird_drop, snow)."""
    paths, labels, groups = _labelled(args.folder, args.labels, "label", args.groups)
    data = {"labels": labels, **({"groups": groups} if groups else {})}
    body = service.call("POST", "/fleet/model", files=_files(paths, "photos"), data=data).json()
    common.warn(body)
    accuracy = body.get("cv_balanced_accuracy")
    how = "" if accuracy is None else f", balanced accuracy {accuracy:.2f}"
    if accuracy is not None and body.get("cv_low") is not None:
        how += f" (95 % interval {body['cv_low']:.2f}–{body['cv_high']:.2f})"
    if body.get("cv_sure_balanced_accuracy") is not None:
        sure, answered = body["cv_sure_balanced_accuracy"], body["cv_answered"]
        how += f"; sure of {answered:.0%} of photos, those at {sure:.2f}"
    common.say(
        args,
        f"fleet model {body['id']} from {body['n_clean']} clean and {body['n_dirty']} dirty "
        f"photos{how}",
        body,
    )


def air_calibrate(service: Service, args: argparse.Namespace) -> None:
    """An air calibration from labelled sky photos: levels 1–10, or the reference pm25 or aqi
    (``--reference``), from sub-folder names or a CSV."""
    column = args.column or args.reference
    paths, values, groups = _labelled(args.folder, args.labels, column, args.groups)
    data = {args.reference: values, **({"groups": groups} if groups else {})}
    params: dict[str, Any] = {"method": args.method} if args.method else {}
    if args.breakpoints:
        params["breakpoints"] = args.breakpoints
    if args.applies_to:
        params["applies_to"] = args.applies_to
    if args.camera_id:
        params["camera_id"] = args.camera_id
    r = service.call(
        "POST",
        "/air/calibration",
        files=_files(paths, "skies"),
        data=data,
        params=params,
    )
    body = r.json()
    common.warn(body)
    graded = ", ".join(body.get("camera_ids") or []) or "every sky camera without its own"
    chosen = body.get("selection")
    why = ""
    if chosen:
        scores = ", ".join(
            f"{m} {v:.2f}" if v is not None else f"{m} unfit" for m, v in chosen["scores"].items()
        )
        why = f"; chosen by {chosen['score']}: {scores}"
    common.say(
        args,
        f"calibration {body['id']} ({body['method']}) from {body['n_images']} images, "
        f"grading {graded}{why}",
        body,
    )


def _pages(service: Service, path: str, params: dict[str, Any]) -> Iterator[str]:
    """The CSV pages of a listing, following its Link: rel="next"."""
    r = service.call("GET", path, params=params)
    while True:
        yield r.text
        link = r.headers.get("link", "")
        if 'rel="next"' not in link:
            return
        r = service.call("GET", link.split(";")[0].strip("<> "))


def export_readings(service: Service, args: argparse.Namespace) -> None:
    """Air readings to CSV, every page of them."""
    params: dict[str, Any] = {"format": "csv", "limit": 10_000}
    if args.camera_id:
        params["camera_id"] = args.camera_id
    for name in ("since", "until"):
        if getattr(args, name):
            params[name] = getattr(args, name)
    n = 0
    with args.out.open("w", newline="") as f, Progress(console=err) as progress:
        task = progress.add_task("readings", total=None)
        for k, page in enumerate(_pages(service, "/air/readings", params)):
            lines = [line + "\n" for line in page.splitlines()]
            f.writelines(lines if k == 0 else lines[1:])
            n += max(len(lines) - 1, 0)
            progress.update(task, completed=n)
    err.print(f"{n} readings written to {args.out}")


def export_history(service: Service, args: argparse.Namespace) -> None:
    """A panel's soiling history (``GET /panels/{id}/history``) to CSV."""
    params = {k: v for k in ("since", "until", "bucket") if (v := getattr(args, k))}
    rows = service.call("GET", f"/panels/{args.panel_id}/history", params=params).json()
    fields = list(rows[0]) if rows else ["start", "end", "frames", "clean", "dirty"]
    with args.out.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields, lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
    err.print(f"{len(rows)} buckets of panel {args.panel_id} written to {args.out}")


def _times(paths: Sequence[Path], fmt: str | None, zone: str) -> list[str | None]:
    """Each frame's capture time (RFC 3339) read from its file name's stem by the strptime
    ``fmt``, in the IANA time zone ``zone``; None each without ``fmt`` (the service stamps
    the frame on arrival). Every name is read before any frame is posted."""
    if fmt is None:
        return [None] * len(paths)
    try:
        tz = ZoneInfo(zone)
    except (ZoneInfoNotFoundError, ValueError):
        raise Failed(f"--timezone {zone!r} is not an IANA time zone (Europe/Rome, UTC)") from None
    out: list[str | None] = []
    for p in paths:
        try:
            out.append(datetime.strptime(p.stem, fmt).replace(tzinfo=tz).isoformat())
        except ValueError:
            raise Failed(f"{p.name}: its name does not read as a time by {fmt!r}") from None
    return out


def replay(service: Service, args: argparse.Namespace) -> None:
    """Post a folder of JPEGs as the camera (a trial), in name order, ``--every`` seconds
    apart, each taken when its name says (``--time-from-name``) or now; each frame's verdict
    in a line of JSON. ``--backfill``: an archive, imported with the admin token
    (``backfill=true``): frames as old as the history kept, raising no alert."""
    paths = [p for p in common.images(args.folder) if p.suffix.lower() in (".jpg", ".jpeg")]
    times = _times(paths, args.time_from_name, args.timezone)
    if args.backfill and args.time_from_name is None:
        raise Failed("--backfill imports an archive: give --time-from-name, when each was taken")
    if not args.backfill and not args.camera_token:
        raise Failed("give --camera-token (the camera's own), or --backfill with the admin token")
    camera = service if args.backfill else Service(service.url, args.camera_token)
    extra = {"backfill": "true"} if args.backfill else {}
    judged = 0
    with Progress(console=err) as progress, contextlib.closing(camera):
        task = progress.add_task(f"replaying as {args.camera_id}", total=len(paths))
        for i, (p, taken) in enumerate(zip(paths, times, strict=True)):
            if i and args.every:
                time.sleep(args.every)
            r = camera.call(
                "POST",
                f"/cameras/{args.camera_id}/frames",
                content=p.read_bytes(),
                headers={"Content-Type": "image/jpeg"},
                params=extra if taken is None else {"captured_at": taken, **extra},
            )
            body = r.json()
            verdict = body.get("verdict") or {}
            judged += verdict.get("reason") is None
            if args.json:
                print(json.dumps({"file": p.name, **body}))
            else:
                print(f"{p.name}: {_verdict_words(verdict)}")
            progress.advance(task)
    summary = f"{len(paths)} frames posted as {args.camera_id}: {judged} judged"
    (err.print if args.json else print)(summary)


def _verdict_words(v: dict[str, Any]) -> str:
    """A frame's verdict as a person reads it: the panel's state, the sky's level, or why
    none."""
    if v.get("reason"):
        return f"no verdict: {v['reason']}"
    if v.get("kind") == "panel":
        return "clean" if v.get("clean") else "needs cleaning"
    if v.get("kind") == "sky":
        return v.get("message") or f"level {v.get('level')}"
    return "measured"


def _registry_commands(sub: Any) -> None:
    """cameras import, panels import."""
    cams = sub.add_parser("cameras", help="register cameras").add_subparsers(
        dest="action", required=True
    )
    c = cams.add_parser("import", help="register cameras (and their sources) from a CSV")
    c.add_argument(
        "csv",
        type=Path,
        help="id,kind,name,lat,lon,panel_id,roi,source_url,every_seconds,username,password",
    )
    c.add_argument("--tokens-out", type=Path, help="write the new tokens to this CSV")
    c.set_defaults(run=import_cameras)

    panels = sub.add_parser("panels", help="register panels").add_subparsers(
        dest="action", required=True
    )
    p = panels.add_parser("import", help="register panels from a CSV (id,name,lat,lon)")
    p.add_argument("csv", type=Path)
    p.set_defaults(run=import_panels)


def _training_commands(sub: Any) -> None:
    """baseline, fleet, air-calibrate."""
    b = sub.add_parser("baseline", help="a panel's clean baseline from a folder of photos")
    b.add_argument("panel_id")
    b.add_argument("folder", type=Path)
    b.add_argument("--camera-id", help="the camera whose region the photos are measured in")
    b.set_defaults(run=baseline)

    f = sub.add_parser("fleet", help="the fleet model from labelled photos")
    f.add_argument("folder", type=Path, help="sub-folders clean, dust, bird_drop, snow")
    f.add_argument("--labels", type=Path, help="a CSV of file,label instead of sub-folders")
    f.add_argument(
        "--groups",
        metavar="COLUMN",
        help="the CSV's column of each photo's panel: the folds keep a panel's photos "
        "together, so the reported accuracy is on panels the model never saw",
    )
    f.set_defaults(run=fleet)

    a = sub.add_parser("air-calibrate", help="an air calibration from labelled sky photos")
    a.add_argument("folder", type=Path, help="sub-folders named by level, or with --labels")
    a.add_argument("--labels", type=Path, help="a CSV of file and the reference column")
    a.add_argument("--reference", choices=["levels", "pm25", "aqi"], default="levels")
    a.add_argument("--column", help="the CSV's column of the values (default: --reference's name)")
    a.add_argument(
        "--groups",
        metavar="COLUMN",
        help="the CSV's column of each photo's day or session: the regression leaves a group "
        "out at a time to choose its penalty and measure its interval (near-duplicate photos "
        "of one day otherwise make it too narrow)",
    )
    a.add_argument(
        "--method",
        choices=["clusters", "regression"],
        help="default: for pm25 or aqi, the one that grades days left out best (the service "
        "compares them); for levels, the clusters",
    )
    a.add_argument(
        "--breakpoints",
        choices=["us_epa", "eu_eaqi"],
        help="the table that makes pm25 levels: US EPA AQI or European Air Quality Index "
        "(default: the European one where the graded cameras stand in Europe)",
    )
    a.add_argument("--applies-to", action="append", help="a sky camera it grades (repeat)")
    a.add_argument("--camera-id", help="the camera whose region the photos are measured in")
    a.set_defaults(run=air_calibrate)


def _export_and_replay_commands(sub: Any) -> None:
    """export readings, export panel-history, replay."""
    ex = sub.add_parser("export", help="readings or panel history to CSV").add_subparsers(
        dest="what", required=True
    )
    r = ex.add_parser("readings", help="air readings (every page)")
    r.add_argument("out", type=Path)
    r.add_argument("--camera-id", action="append")
    r.add_argument("--since")
    r.add_argument("--until")
    r.set_defaults(run=export_readings)
    h = ex.add_parser("panel-history", help="a panel's soiling history")
    h.add_argument("panel_id")
    h.add_argument("out", type=Path)
    h.add_argument("--bucket", choices=["hour", "day"])
    h.add_argument("--since")
    h.add_argument("--until")
    h.set_defaults(run=export_history)

    rp = sub.add_parser("replay", help="post a folder of JPEGs as a camera (a trial)")
    rp.add_argument("camera_id")
    rp.add_argument("folder", type=Path)
    rp.add_argument("--camera-token", help="the camera's own token (not with --backfill)")
    rp.add_argument(
        "--backfill",
        action="store_true",
        help="import an archive with the admin token (VANTAGE_TOKEN): frames as old as the "
        "history the service keeps, graded in their own time, raising no alert",
    )
    rp.add_argument("--every", type=float, default=0.0, help="seconds between frames")
    rp.add_argument(
        "--time-from-name",
        metavar="FORMAT",
        help="each frame was taken when its name says, read by this strptime format "
        "(%%Y%%m%%d-%%H%%M reads 20250514-0900.jpg); else it is stamped on arrival",
    )
    rp.add_argument("--timezone", default="UTC", help="the zone of those times (Europe/Rome)")
    rp.set_defaults(run=replay)


def parser() -> argparse.ArgumentParser:
    top = argparse.ArgumentParser(
        prog="vantage",
        description="Bulk work against a running Vantage service (VANTAGE_URL, VANTAGE_TOKEN).",
    )
    top.add_argument("--url", default=os.environ.get("VANTAGE_URL", "http://127.0.0.1:8000"))
    top.add_argument(
        "--token", default=os.environ.get("VANTAGE_TOKEN"), help="default: VANTAGE_TOKEN"
    )
    top.add_argument(
        "--json",
        action="store_true",
        help="print the service's answers as JSON (a line a frame for replay) instead of a "
        "line a person reads",
    )
    sub = top.add_subparsers(dest="command", required=True, metavar="COMMAND")

    _registry_commands(sub)
    _training_commands(sub)
    _export_and_replay_commands(sub)
    stations.commands(sub)
    energy.commands(sub)
    return top


def main(argv: Sequence[str] | None = None) -> int:
    args = parser().parse_args(argv)
    service = Service(args.url, args.token)
    try:
        args.run(service, args)
    except Failed as exc:
        err.print(f"[red]error:[/] {exc}", highlight=False)
        return 1
    finally:
        service.close()
    return 0
