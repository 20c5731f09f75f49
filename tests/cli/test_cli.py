"""The ``vantage`` command against a running service (uvicorn on 127.0.0.1), each command."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any
from zoneinfo import ZoneInfo

import httpx2 as httpx
import numpy as np
import pytest

from app import cli
from tests.factories import ADMIN_TOKEN
from tests.factories.air import sky_jpeg
from tests.factories.solar import CLEAN_RGB, clean_set, panel_jpeg

ADMIN = {"Authorization": f"Bearer {ADMIN_TOKEN}"}
COMMANDS = (
    ["cameras", "import"],
    ["panels", "import"],
    ["baseline"],
    ["fleet"],
    ["air-calibrate"],
    ["export", "readings"],
    ["export", "panel-history"],
    ["replay"],
    ["stations", "import"],
    ["stations", "readings"],
    ["energy", "import"],
)


def vantage(live: str, *args: str, token: str | None = ADMIN_TOKEN) -> int:
    base = ["--url", live] + (["--token", token] if token else [])
    return cli.main([*base, *args])


def write_csv(path: Path, rows: list[dict[str, Any]]) -> Path:
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    return path


def test_every_command_has_help(capsys: pytest.CaptureFixture[str]) -> None:
    for command in COMMANDS:
        with pytest.raises(SystemExit) as done:
            cli.main([*command, "--help"])
        assert done.value.code == 0
        assert f"usage: vantage {' '.join(command)}" in capsys.readouterr().out
    installed = subprocess.run(
        [sys.executable, "-m", "app.cli", "--help"], capture_output=True, text=True, check=True
    )
    assert "air-calibrate" in installed.stdout


def test_cameras_and_panels_from_csv(
    live: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    panels = write_csv(
        tmp_path / "panels.csv", [{"id": "p1", "name": "Row A", "lat": "45.1", "lon": "9.2"}]
    )
    assert vantage(live, "panels", "import", str(panels)) == 0
    cameras = write_csv(
        tmp_path / "cameras.csv",
        [
            {"id": "s1", "kind": "sky", "name": "Roof", "lat": "45.46", "lon": "9.19",
             "panel_id": "", "roi": "[0, 0, 160, 55]", "source_url": "", "every_seconds": ""},
            {"id": "pc", "kind": "panel", "name": "", "lat": "", "lon": "", "panel_id": "p1",
             "roi": "", "source_url": "rtsp://op:pw@10.1.2.3/live", "every_seconds": "60"},
        ],
    )  # fmt: skip
    tokens = tmp_path / "tokens.csv"
    assert vantage(live, "cameras", "import", str(cameras), "--tokens-out", str(tokens)) == 0
    with tokens.open() as f:
        got = list(csv.DictReader(f))
    assert [r["id"] for r in got] == ["s1", "pc"]
    assert all(r["token"].startswith("vc") for r in got)
    listed = {c["id"]: c for c in httpx.get(f"{live}/cameras", headers=ADMIN).json()}
    assert listed["s1"]["roi"] == [0, 0, 160, 55]
    assert listed["pc"]["panel_id"] == "p1"
    assert listed["pc"]["source"]["url"] == "rtsp://10.1.2.3/live"
    assert listed["pc"]["source"]["username"] == "op"
    # the same again: the service's refusal, with its reason, and status 1
    capsys.readouterr()
    assert vantage(live, "cameras", "import", str(cameras)) == 1
    assert "409" in capsys.readouterr().err
    broken = write_csv(tmp_path / "broken.csv", [{"id": "x", "kind": ""}])
    assert vantage(live, "cameras", "import", str(broken)) == 1
    assert "row 2: id and kind are needed" in capsys.readouterr().err


def test_air_calibration_replay_and_readings_export(
    live: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    skies = tmp_path / "skies"
    for level in (1, 3, 5, 7, 10):
        (skies / str(level)).mkdir(parents=True)
        for k in range(8):
            (skies / str(level) / f"{k}.jpg").write_bytes(sky_jpeg(level, seed=10 * level + k))
    r = httpx.post(
        f"{live}/cameras", json={"id": "s1", "kind": "sky", "roi": [0, 0, 160, 55]}, headers=ADMIN
    )
    token = r.json()["token"]
    assert (
        vantage(
            live, "--json", "air-calibrate", str(skies), "--applies-to", "s1", "--camera-id", "s1"
        )
        == 0
    )
    made = json.loads(capsys.readouterr().out)
    assert (made["n_images"], made["camera_ids"]) == (40, ["s1"])
    frames = tmp_path / "frames"
    frames.mkdir()
    for k, level in enumerate((10, 7, 3)):
        (frames / f"{k:02d}.jpg").write_bytes(sky_jpeg(level, seed=500 + k))
    assert vantage(live, "--json", "replay", "s1", str(frames), "--camera-token", token) == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert [x["verdict"]["level"] for x in lines] == [10, 7, 3]
    out = tmp_path / "readings.csv"
    assert vantage(live, "export", "readings", str(out), "--camera-id", "s1") == 0
    with out.open() as f:
        rows = list(csv.DictReader(f))
    assert sorted(r["level"] for r in rows) == ["10", "3", "7"]
    assert "calibration_id" in rows[0]


def test_baseline_fleet_and_history(
    live: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert httpx.post(f"{live}/panels", json={"id": "p1"}, headers=ADMIN).status_code == 201
    clean = tmp_path / "clean"
    clean.mkdir()
    for i, data in enumerate(clean_set(12)):
        (clean / f"{i}.jpg").write_bytes(data)
    assert vantage(live, "baseline", "p1", str(clean)) == 0
    assert httpx.get(f"{live}/panels/p1/baseline", headers=ADMIN).status_code == 200
    photos = tmp_path / "fleet"
    rng = np.random.default_rng(5)
    sand = np.array([190.0, 180.0, 160.0])
    for label in ("clean", "dirty"):
        (photos / label).mkdir(parents=True)
    for i in range(8):
        c = CLEAN_RGB + rng.normal(0, 6, 3)
        (photos / "clean" / f"c{i}.jpg").write_bytes(panel_jpeg(c, seed=i))
        (photos / "dirty" / f"d{i}.jpg").write_bytes(panel_jpeg(0.5 * c + 0.5 * sand, seed=100 + i))
    capsys.readouterr()
    assert vantage(live, "fleet", str(photos)) == 0
    assert "; sure of 100% of photos, those at 1.00" in capsys.readouterr().out
    assert httpx.get(f"{live}/fleet/model", headers=ADMIN).json()["n_groups"] is None
    # each clean photo and its sandy copy are one panel's: the folds keep them together
    rows = [
        {"file": f"{label}/{label[0]}{i}.jpg", "label": label, "panel": f"row-{i}"}
        for label in ("clean", "dirty")
        for i in range(8)
    ]
    labels = write_csv(tmp_path / "fleet.csv", rows)
    assert vantage(live, "fleet", str(photos), "--groups", "panel") == 1
    assert vantage(live, "fleet", str(photos), "--labels", str(labels), "--groups", "panel") == 0
    assert httpx.get(f"{live}/fleet/model", headers=ADMIN).json()["n_groups"] == 8
    out = tmp_path / "history.csv"
    assert vantage(live, "export", "panel-history", "p1", str(out), "--bucket", "day") == 0
    assert out.read_text().splitlines()[0].startswith("start,end,frames")


def test_clear_errors(live: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert vantage("http://127.0.0.1:9", "panels", "import", str(tmp_path / "none.csv")) == 1
    assert "cannot read" in capsys.readouterr().err
    panels = write_csv(tmp_path / "p.csv", [{"id": "p9"}])
    assert vantage("http://127.0.0.1:9", "panels", "import", str(panels)) == 1
    assert "cannot reach the service" in capsys.readouterr().err
    assert vantage(live, "panels", "import", str(panels), token="wrong") == 1
    assert "401" in capsys.readouterr().err
    assert vantage(live, "baseline", "p1", str(tmp_path)) == 1
    assert "no images" in capsys.readouterr().err


def test_a_labels_csv_chooses_the_images_and_its_column(
    live: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    skies = tmp_path / "archive"
    skies.mkdir()
    rows = []
    for level in (2, 5, 9):
        for k in range(6):
            name = f"l{level}-{k}.jpg"
            (skies / name).write_bytes(sky_jpeg(level, seed=20 * level + k))
            rows.append({"file": name, "station_grade": level, "day": f"2026-05-0{k + 1}"})
    (skies / "not-labelled.jpg").write_bytes(sky_jpeg(5, seed=999))
    labels = write_csv(tmp_path / "grades.csv", rows)
    assert (
        vantage(
            live,
            "--json",
            "air-calibrate",
            str(skies),
            "--labels",
            str(labels),
            "--column",
            "station_grade",
        )
        == 0
    )
    done = capsys.readouterr()
    assert json.loads(done.out)["n_images"] == 18
    assert "1 of the 19 images" in done.err
    before = httpx.get(f"{live}/air/calibration", headers=ADMIN).json()["id"]
    more = write_csv(tmp_path / "more.csv", [*rows, {"file": "gone.jpg", "station_grade": 3}])
    assert (
        vantage(
            live, "air-calibrate", str(skies), "--labels", str(more), "--column", "station_grade"
        )
        == 1
    )
    assert "names 1 files not in" in capsys.readouterr().err
    assert httpx.get(f"{live}/air/calibration", headers=ADMIN).json()["id"] == before
    # the regression measures its interval a day left out at a time
    grade = ["--labels", str(labels), "--column", "station_grade", "--method", "regression"]
    assert vantage(live, "--json", "air-calibrate", str(skies), *grade, "--groups", "day") == 0
    assert json.loads(capsys.readouterr().out)["regression"]["sigma_from"] == "days left out"
    assert vantage(live, "air-calibrate", str(skies), "--groups", "day") == 1
    assert "give --labels" in capsys.readouterr().err
    assert vantage(live, "air-calibrate", str(skies), *grade, "--groups", "hour") == 1
    assert "has no column hour" in capsys.readouterr().err
    undated = write_csv(tmp_path / "undated.csv", [{**rows[0], "day": ""}, *rows[1:]])
    assert (
        vantage(
            live,
            "air-calibrate",
            str(skies),
            *grade[2:],
            "--labels",
            str(undated),
            "--groups",
            "day",
        )
        == 1
    )
    assert "l2-0.jpg has no day" in capsys.readouterr().err


def test_replay_takes_each_frames_time_from_its_name(
    live: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    r = httpx.post(f"{live}/cameras", json={"id": "s2", "kind": "sky"}, headers=ADMIN)
    token = r.json()["token"] + "\r\n"  # as cut from a CSV written on another system
    rome = ZoneInfo("Europe/Rome")
    taken = [
        (datetime.now(rome) - timedelta(days=1, hours=h)).replace(second=0, microsecond=0)
        for h in (3, 2)
    ]
    frames = tmp_path / "frames"
    frames.mkdir()
    for k, t in enumerate(taken):
        (frames / f"{t:%Y%m%d-%H%M}.jpg").write_bytes(sky_jpeg(7, seed=k))
    args = ["--json", "replay", "s2", str(frames), "--camera-token", token, "--time-from-name"]
    assert vantage(live, *args, "%Y%m%d-%H%M", "--timezone", "Europe/Rome") == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert [datetime.fromisoformat(x["captured_at"]) for x in lines] == taken
    (frames / "snapshot.jpg").write_bytes(sky_jpeg(7, seed=9))
    assert vantage(live, *args, "%Y%m%d-%H%M") == 1  # read before anything is posted
    assert "snapshot.jpg: its name does not read" in capsys.readouterr().err
    assert vantage(live, *args, "%Y%m%d-%H%M", "--timezone", "Mars/Olympus") == 1
    assert "not an IANA time zone" in capsys.readouterr().err
    listed = httpx.get(f"{live}/cameras/s2/frames", headers=ADMIN)
    assert len(listed.json()) == 2


def test_replay_backfills_an_archive_with_the_admin_token(
    live: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--backfill``: the admin token posts each frame with backfill=true, at its name's
    time (required); without it, a camera token is."""
    made = httpx.post(f"{live}/cameras", json={"id": "s3", "kind": "sky"}, headers=ADMIN)
    assert made.status_code == 201
    taken = [
        (datetime.now(UTC) - timedelta(days=2, hours=h)).replace(second=0, microsecond=0)
        for h in (2, 1)
    ]
    frames = tmp_path / "archive"
    frames.mkdir()
    for k, t in enumerate(taken):
        (frames / f"{t:%Y%m%d-%H%M}.jpg").write_bytes(sky_jpeg(7, seed=20 + k))
    assert vantage(live, "replay", "s3", str(frames), "--backfill") == 1
    assert "give --time-from-name" in capsys.readouterr().err
    assert vantage(live, "replay", "s3", str(frames)) == 1
    assert "give --camera-token" in capsys.readouterr().err
    args = ["--json", "replay", "s3", str(frames), "--backfill", "--time-from-name"]
    assert vantage(live, *args, "%Y%m%d-%H%M") == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert [datetime.fromisoformat(x["captured_at"]) for x in lines] == taken
    assert vantage(live, *args, "%Y%m%d-%H%M", token="not-the-admin") == 1  # 401


def test_stations_and_their_readings_are_imported(
    live: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``stations import`` registers them; ``stations readings`` sends a station's 12,000
    readings in chunks of 5,000, a bad row named by its line in the file."""
    stations = write_csv(
        tmp_path / "stations.csv",
        [{"id": "vm", "name": "Viale Marche", "lat": "45.496", "lon": "9.193"}],
    )
    assert vantage(live, "stations", "import", str(stations)) == 0
    assert "1 stations registered" in capsys.readouterr().out
    start = datetime(2025, 1, 1, tzinfo=UTC)
    rows = [
        {"at": (start + timedelta(minutes=10 * k)).isoformat(), "pm25": f"{5 + k % 40}"}
        for k in range(12_000)
    ]
    readings = write_csv(tmp_path / "readings.csv", rows)
    assert vantage(live, "stations", "readings", "vm", str(readings)) == 0
    assert "12000 readings of vm stored" in capsys.readouterr().out
    latest = httpx.get(f"{live}/air/stations/vm").json()["latest"]
    assert datetime.fromisoformat(latest["at"]) == start + timedelta(minutes=10 * 11_999)
    rows[7_000]["pm25"] = "-3"
    bad = write_csv(tmp_path / "bad.csv", rows)
    assert vantage(live, "stations", "readings", "vm", str(bad)) == 1
    assert "rows 5002–10001" in capsys.readouterr().err


def test_a_farms_export_is_imported_panel_by_panel(
    live: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``energy import``: an hourly SCADA export, a column per panel (one of them mapped with
    --panel) and the farm's plane-of-array insolation, summed by day; a NaN named by its row."""
    for pid in ("p1", "p2"):
        body = {"id": pid, "kwp": 0.4}
        assert httpx.post(f"{live}/panels", json=body, headers=ADMIN).status_code == 201
    first = datetime.now(UTC).replace(hour=0, minute=0, second=0, microsecond=0)
    first -= timedelta(days=20)
    rows = [
        {
            "timestamp": (first + timedelta(hours=h)).isoformat(),
            "p1": "0.1",
            "inverter 2": "0.05",
            "poa_kwh_m2": "0.25",
        }
        for h in range(24 * 20)
    ]
    export = write_csv(tmp_path / "scada.csv", rows)
    args = ["energy", "import", str(export), "--panel", "p1=p1", "--panel", "inverter 2=p2"]
    assert vantage(live, *args) == 0
    assert "40 days of 2 panels stored" in capsys.readouterr().out
    days = httpx.get(f"{live}/panels/p2/energy", headers=ADMIN).json()
    assert len(days) == 20
    assert days[0]["kwh"] == pytest.approx(1.2)
    assert days[0]["poa_kwh_m2"] == pytest.approx(6.0)
    assert days[0]["expected_kwh"] == pytest.approx(2.4)  # 0.4 kW × 6 kWh/m²
    assert days[0]["expected_from"] == "poa"
    rows[30]["p1"] = "nan"
    assert vantage(live, "energy", "import", str(write_csv(tmp_path / "bad.csv", rows))) == 1
    assert "row 32: p1 is nan" in capsys.readouterr().err


def test_a_crlf_csv_leaves_no_carriage_return(
    live: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cameras = tmp_path / "cameras.csv"  # as a spreadsheet on Windows saves it
    cameras.write_bytes(b"id,kind,name\r\ncr-1,sky,North\r\ncr-2,sky,South\r\n")
    tokens = tmp_path / "tokens.csv"
    assert vantage(live, "cameras", "import", str(cameras), "--tokens-out", str(tokens)) == 0
    listed = {c["id"]: c["name"] for c in httpx.get(f"{live}/cameras", headers=ADMIN).json()}
    assert (listed["cr-1"], listed["cr-2"]) == ("North", "South")
    written = tokens.read_bytes()
    assert b"\r" not in written  # cut -d, -f2 tokens.csv gives the token alone
    assert [line.split(b",")[0] for line in written.splitlines()] == [b"id", b"cr-1", b"cr-2"]
    assert "2 cameras registered" in capsys.readouterr().err


def test_a_photo_twice_in_a_folder_is_refused_with_its_paths(
    live: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert httpx.post(f"{live}/panels", json={"id": "p2"}, headers=ADMIN).status_code == 201
    clean = tmp_path / "clean"
    (clean / "monday").mkdir(parents=True)
    (clean / "copy").mkdir()
    for i, data in enumerate(clean_set(6)):
        (clean / "monday" / f"{i}.jpg").write_bytes(data)
    (clean / "copy" / "3.jpg").write_bytes((clean / "monday" / "3.jpg").read_bytes())
    capsys.readouterr()
    assert vantage(live, "baseline", "p2", str(clean)) == 1
    said = capsys.readouterr().err.replace("\n", "")
    assert "copy/3.jpg and" in said
    assert "monday/3.jpg are the same photo" in said
    assert httpx.get(f"{live}/panels/p2/baseline", headers=ADMIN).status_code == 404
    # a labels CSV naming a file bare that two sub-folders hold: which one is meant?
    (clean / "copy" / "3.jpg").write_bytes(clean_set(7)[6])
    labels = write_csv(tmp_path / "labels.csv", [{"file": "3.jpg", "label": "clean"}])
    assert vantage(live, "fleet", str(clean), "--labels", str(labels)) == 1
    said = capsys.readouterr().err.replace("\n", "")
    assert "holds it 2 times: copy/3.jpg, monday/3.jpg" in said


def test_each_command_ends_with_a_line_a_person_reads(
    live: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert httpx.post(f"{live}/panels", json={"id": "p3"}, headers=ADMIN).status_code == 201
    clean = tmp_path / "clean"
    clean.mkdir()
    for i, data in enumerate(clean_set(8)):
        (clean / f"{i}.jpg").write_bytes(data)
    capsys.readouterr()
    assert vantage(live, "baseline", "p3", str(clean)) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1
    assert out[0].startswith("baseline ")
    assert "from 8 photos" in out[0]
    assert vantage(live, "--json", "baseline", "p3", str(clean)) == 0
    assert json.loads(capsys.readouterr().out)["n"] == 8
