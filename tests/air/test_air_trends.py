"""GET /air/readings?aggregate=hourly|daily: every reading in the range counts, in the local
hours and days of the time zone asked for, checked against the same means computed here from
the readings one by one."""

from __future__ import annotations

import csv
import io
from collections import defaultdict
from datetime import UTC, datetime, timedelta, timezone
from typing import Any
from zoneinfo import ZoneInfo

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine

from tests.factories import pages
from tests.factories.air import Reading, store


def expected(readings: list[Reading], bucket: str, tz: ZoneInfo) -> list[dict[str, Any]]:
    """The buckets, newest first, from each reading's own local time."""
    groups: dict[tuple[str, datetime, datetime], list[int]] = defaultdict(list)
    for cam, at, level in readings:
        if level is None:
            continue
        local = at.astimezone(tz)
        if bucket == "hourly":
            start = local.replace(minute=0, second=0, microsecond=0)
            end = start.astimezone(UTC) + timedelta(hours=1)
        else:
            start = datetime(local.year, local.month, local.day, tzinfo=tz)
            nxt = start.date() + timedelta(days=1)
            end = datetime(nxt.year, nxt.month, nxt.day, tzinfo=tz)
        groups[(cam, start, end)].append(level)
    out = [
        {
            "camera_id": cam,
            "start": start.astimezone(UTC),
            "end": end.astimezone(UTC),
            "offset": start.utcoffset(),
            "n": len(v),
            "mean_level": float(np.mean(v)),
            "min_level": min(v),
            "max_level": max(v),
        }
        for (cam, start, end), v in groups.items()
    ]
    return sorted(out, key=lambda d: (d["start"], d["camera_id"]), reverse=True)


def fetch(client: TestClient, **params: Any) -> list[dict[str, Any]]:
    out: list[dict[str, Any]] = []
    while True:
        r = client.get("/air/readings", params={**params, "limit": 10_000, "offset": len(out)})
        assert r.status_code == 200, r.text
        page = r.json()
        out += page
        if len(page) < 10_000:
            return out


def as_expected(got: list[dict[str, Any]]) -> list[dict[str, Any]]:
    rows = []
    for b in got:
        start = datetime.fromisoformat(b["start"])
        rows.append(
            {
                "camera_id": b["camera_id"],
                "start": start.astimezone(UTC),
                "end": datetime.fromisoformat(b["end"]).astimezone(UTC),
                "offset": start.utcoffset(),
                "n": b["n"],
                "mean_level": pytest.approx(b["mean_level"], abs=1e-9),
                "min_level": b["min_level"],
                "max_level": b["max_level"],
            }
        )
    return rows


def test_local_hours_and_days_across_zones_and_clock_changes(
    client: TestClient, engine: Engine
) -> None:
    """Two cameras, a reading every 7 to 23 minutes (some ungraded) over the last week of
    October 2026, when Europe puts its clocks back (25 October: the hour 02:00–03:00 comes
    twice) and New York does not yet. India (+5:30) and Nepal (+5:45) have hours that are not
    UTC's. Before, buckets were UTC's whatever the city."""
    rng = np.random.default_rng(7)
    readings: list[Reading] = []
    for cam in ("sky-a", "sky-b"):
        at = datetime(2026, 10, 22, tzinfo=UTC)
        while at < datetime(2026, 10, 29, tzinfo=UTC):
            level = None if rng.random() < 0.1 else int(rng.integers(1, 11))
            readings.append((cam, at, level))
            at += timedelta(minutes=int(rng.integers(7, 24)), seconds=int(rng.integers(0, 60)))
    store(engine, readings)
    since, until = datetime(2026, 10, 23, 3, 10, tzinfo=UTC), datetime(2026, 10, 28, tzinfo=UTC)
    inside = [r for r in readings if since <= r[1] < until]
    for zone in ("UTC", "Europe/Rome", "Asia/Kolkata", "Asia/Kathmandu", "America/New_York"):
        for bucket in ("hourly", "daily"):
            got = fetch(
                client,
                aggregate=bucket,
                tz=zone,
                since=since.isoformat(),
                until=until.isoformat(),
            )
            want = expected(inside, bucket, ZoneInfo(zone))
            assert as_expected(got) == want, (zone, bucket)
    # the autumn night in Rome: 02:00 +02:00 and 02:00 +01:00 are two hours
    rome = fetch(client, aggregate="hourly", tz="Europe/Rome", camera_id="sky-a")
    twice = [b["start"] for b in rome if b["start"][11:16] == "02:00" and "10-25" in b["start"]]
    assert sorted(twice) == ["2026-10-25T02:00:00+01:00", "2026-10-25T02:00:00+02:00"]
    day = next(
        b for b in fetch(client, aggregate="daily", tz="Europe/Rome") if "10-25" in b["start"]
    )
    hours = (
        datetime.fromisoformat(day["end"]) - datetime.fromisoformat(day["start"])
    ).total_seconds()
    assert hours == 25 * 3600


@pytest.mark.slow
def test_every_reading_in_the_range_counts(client: TestClient, engine: Engine) -> None:
    """120,000 readings (a city's cameras over a few days). Before, only the newest 100,000
    were read: the oldest days' means came from part of their readings, or were missing."""
    rng = np.random.default_rng(3)
    t0 = datetime(2026, 6, 1, tzinfo=UTC)
    readings: list[Reading] = [
        (f"sky-{k % 40:02d}", t0 + timedelta(seconds=6 * (k // 40)), int(rng.integers(1, 11)))
        for k in range(120_000)
    ]
    store(engine, readings)
    got = fetch(client, aggregate="daily")
    assert sum(b["n"] for b in got) == 120_000
    assert as_expected(got) == expected(readings, "daily", ZoneInfo("UTC"))


@pytest.mark.parametrize("zone", ["Mars/Olympus_Mons", "../../etc/passwd", "", "+05:30"])
def test_an_unknown_time_zone_is_422(client: TestClient, zone: str) -> None:
    r = client.get("/air/readings", params={"aggregate": "daily", "tz": zone})
    assert r.status_code == 422, r.text
    assert r.headers["content-type"] == "application/problem+json"


def test_offsets_are_fixed_in_the_answer() -> None:
    """A bucket's start carries the offset it had then (checked on the helper's output)."""
    from app.air.services.readings import _bucket

    rome = ZoneInfo("Europe/Rome")
    start, end = _bucket(datetime(2026, 10, 25, 2, 0), timedelta(hours=1), "hourly", rome)
    assert start.utcoffset() == timedelta(hours=1)
    assert start.tzinfo == timezone(timedelta(hours=1))
    assert end - start == timedelta(hours=1)
    start, end = _bucket(datetime(2026, 10, 25), timedelta(hours=2), "daily", rome)
    assert (start.utcoffset(), end.utcoffset()) == (timedelta(hours=2), timedelta(hours=1))
    assert end - start == timedelta(hours=25)


def test_the_range_is_cut_where_the_clocks_change() -> None:
    """Rome puts its clocks back at 01:00 UTC on 25 October 2026 and forward at 01:00 UTC on
    28 March 2027 (the EU's rule): the pieces change offset there, to the second."""
    from app.air.services.readings import _offset_spans

    spans = _offset_spans(
        ZoneInfo("Europe/Rome"),
        datetime(2026, 10, 20, 7, 13, 5, 123456, tzinfo=UTC),
        datetime(2027, 4, 2, tzinfo=UTC),
    )
    assert spans == [
        (None, datetime(2026, 10, 25, 1, tzinfo=UTC), timedelta(hours=2)),
        (
            datetime(2026, 10, 25, 1, tzinfo=UTC),
            datetime(2027, 3, 28, 1, tzinfo=UTC),
            timedelta(hours=1),
        ),
        (datetime(2027, 3, 28, 1, tzinfo=UTC), None, timedelta(hours=2)),
    ]
    kolkata = _offset_spans(
        ZoneInfo("Asia/Kolkata"),
        datetime(2026, 1, 1, tzinfo=UTC),
        datetime(2026, 12, 31, tzinfo=UTC),
    )
    assert kolkata == [(None, None, timedelta(hours=5, minutes=30))]


def test_readings_page_by_cursor(client: TestClient, engine: Engine) -> None:
    """Following ``Link: rel=next`` gives every reading once, newest first (ties at one instant
    included), and readings arriving meanwhile push nothing onto the next page: paged by
    ``offset``, the newest row of a page came back at the top of the next."""
    t0 = datetime(2026, 5, 1, tzinfo=UTC)
    at = [t0 + timedelta(minutes=m) for m in (0, 5, 5, 5, 10, 15, 20)]  # three at one instant
    readings: list[Reading] = [(f"sky-{k % 2}", t, 1 + k) for k, t in enumerate(at)]
    store(engine, readings)
    expected = sorted(
        (
            (t.isoformat().replace("+00:00", "Z"), f"f{k:07d}")
            for k, (_, t, _) in enumerate(readings)
        ),
        reverse=True,
    )
    got = pages(client, "/air/readings", {"limit": 3})
    assert [len(p) for p in got] == [3, 3, 1]
    assert [(r["captured_at"], r["frame_id"]) for p in got for r in p] == expected

    # one camera, and a range: the cursor keeps both
    one = pages(
        client, "/air/readings", {"limit": 2, "camera_id": "sky-0", "since": "2026-05-01T00:05:00Z"}
    )
    assert [r["frame_id"] for p in one for r in p] == [
        fid for t, fid in expected if int(fid[1:]) % 2 == 0 and t >= "2026-05-01T00:05"
    ]

    first = client.get("/air/readings", params={"limit": 3})
    next_url = first.headers["link"].split(";")[0].strip("<>")
    store(engine, [("sky-9", t0 + timedelta(hours=1), 5)], start=100)  # posted meanwhile
    second = client.get(next_url).json()
    assert [r["frame_id"] for r in second] == [fid for _, fid in expected[3:6]]
    by_offset = client.get("/air/readings", params={"limit": 3, "offset": 3}).json()
    assert by_offset[0]["frame_id"] == expected[2][1]  # page 1's last row, again


def test_bad_paging_is_422(client: TestClient) -> None:
    for params in (
        {"cursor": "not-a-cursor"},
        {"cursor": "MjAyNi0wNS0wMQ=="},  # a time without an offset, and no id
        {"offset": 100_001},
        {"cursor": "MjAyNi0wNS0wMVQwMDowMDowMCswMDowMHxmMQ==", "aggregate": "daily"},
    ):
        r = client.get("/air/readings", params=params)
        assert r.status_code == 422, params
        assert r.headers["content-type"] == "application/problem+json"


def test_readings_of_several_cameras_in_one_request(client: TestClient, engine: Engine) -> None:
    """A district's dashboard asks for three of a city's cameras: ``camera_id`` repeated. Before,
    the last one given won without a word (the readings of one camera, answered as if of all
    three)."""
    t0 = datetime(2026, 5, 1, tzinfo=UTC)
    readings: list[Reading] = [
        (f"sky-{k % 5}", t0 + timedelta(minutes=7 * k), 1 + k % 10) for k in range(60)
    ]
    store(engine, readings)
    wanted = ("sky-1", "sky-3", "sky-4")
    inside = [(k, r) for k, r in enumerate(readings) if r[0] in wanted]
    newest_first = sorted(
        ((t.isoformat().replace("+00:00", "Z"), f"f{k:07d}") for k, (_, t, _) in inside),
        reverse=True,
    )
    got = pages(client, "/air/readings", {"camera_id": list(wanted), "limit": 7})
    assert [len(p) for p in got] == [7, 7, 7, 7, 7, 1]  # the cursor keeps all three ids
    assert [(r["captured_at"], r["frame_id"]) for p in got for r in p] == newest_first

    hourly = fetch(client, aggregate="hourly", camera_id=list(wanted))
    assert as_expected(hourly) == expected([r for _, r in inside], "hourly", ZoneInfo("UTC"))

    # a misspelt id is named, with every other unknown one, not taken for a camera without data
    r = client.get("/air/readings", params={"camera_id": ["sky-1", "sky-7", "sky-x"]})
    assert r.status_code == 404, r.text
    assert r.json()["unknown"] == ["sky-7", "sky-x"]
    r = client.get("/air/readings", params={"camera_id": [f"sky-{k}" for k in range(101)]})
    assert r.status_code == 422, r.text  # at most 100 at once


@pytest.mark.parametrize(
    "query",
    [
        "since=2026-05-01T00:00:00Z&since=2026-06-01T00:00:00Z",
        "aggregate=daily&aggregate=hourly",
        "limit=5&limit=50",
        "camera_id=sky-1&tz=UTC&tz=Asia/Kolkata",
    ],
)
def test_a_parameter_that_takes_one_value_given_twice_is_422(
    client: TestClient, engine: Engine, query: str
) -> None:
    store(engine, [("sky-1", datetime(2026, 5, 1, tzinfo=UTC), 5)])
    r = client.get(f"/air/readings?{query}")
    assert r.status_code == 422, r.text
    assert r.headers["content-type"] == "application/problem+json"
    assert r.json()["code"] == "repeated_parameter"


def test_readings_and_their_means_as_csv(client: TestClient, engine: Engine) -> None:
    """``format=csv``: the same rows as the JSON answer, a header and one line each (empty
    cells for nulls), paged alike (the Link header to the next page keeps the format), the
    means too: what a spreadsheet imports from a URL."""
    t0 = datetime(2026, 5, 1, tzinfo=UTC)
    readings: list[Reading] = [
        ("sky-a", t0 + timedelta(minutes=10 * k), None if k == 2 else 1 + k) for k in range(7)
    ]
    store(engine, readings)

    def table(r: Any) -> list[dict[str, str]]:
        assert r.status_code == 200, r.text
        assert r.headers["content-type"] == "text/csv; charset=utf-8"
        return list(csv.DictReader(io.StringIO(r.text)))

    def cells(rows: list[dict[str, Any]]) -> list[dict[str, str]]:
        return [{k: "" if v is None else str(v) for k, v in row.items()} for row in rows]

    params = {"limit": 4, "since": "2026-05-01T00:00:00Z"}
    first = client.get("/air/readings", params={**params, "format": "csv"})
    first_json = client.get("/air/readings", params=params)
    rows = table(first)
    assert list(rows[0]) == [
        "camera_id", "frame_id", "captured_at", "level", "category", "smoothed_level", "reason",
        "uncertain", "estimate", "estimate_low", "estimate_high", "estimate_unit",
        "calibration_id", "probability", "smoothed_estimate", "smoothed_low", "smoothed_high",
        "smoothed_probability", "poor_probability",
    ]  # fmt: skip
    assert rows == cells(first_json.json())
    assert [r["frame_id"] for r in rows] == ["f0000006", "f0000005", "f0000004", "f0000003"]
    next_csv = first.headers["link"].split(";")[0].strip("<>")
    assert "format=csv" in next_csv
    rest = table(client.get(next_csv))
    rest_json = client.get(first_json.headers["link"].split(";")[0].strip("<>")).json()
    assert rest == cells(rest_json)
    assert [(r["frame_id"], r["level"]) for r in rest] == [
        ("f0000002", ""), ("f0000001", "2"), ("f0000000", "1")
    ]  # fmt: skip

    daily = {"aggregate": "daily", "since": "2026-05-01T00:00:00Z"}
    means = table(client.get("/air/readings", params={**daily, "format": "csv"}))
    assert means == cells(client.get("/air/readings", params=daily).json())
    assert [(m["n"], m["min_level"], m["max_level"]) for m in means] == [("6", "1.0", "7.0")]
