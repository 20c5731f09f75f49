"""The farm operator is told: task and baseline events to the solar webhook (Standard
Webhooks), kept in the outbox until delivered."""

from __future__ import annotations

import base64
import hashlib
import hmac
import json
from datetime import datetime, timedelta
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.platform import outbox
from tests.factories import Clock, bearer, recorder, served
from tests.factories.solar import CLEAN_RGB, DUST, clean_set, panel_jpeg, train

SECRET = "whsec_" + base64.b64encode(bytes(range(32))).decode()


@pytest.fixture
def farm(client: TestClient, admin: dict[str, str], app: Any, clock: Clock) -> dict[str, Any]:
    assert client.post("/panels", json={"id": "p1"}, headers=admin).status_code == 201
    cam = client.post(
        "/cameras", json={"id": "c1", "kind": "panel", "panel_id": "p1"}, headers=admin
    ).json()
    robot = client.post("/robots", json={"id": "r1"}, headers=admin).json()["token"]
    return {"camera": cam["token"], "robot": robot, "clock": clock, "app": app}


def frame(client: TestClient, farm: dict[str, Any], rgb: np.ndarray, seed: int) -> None:
    farm["clock"].advance(minutes=10)
    r = client.post(
        "/cameras/c1/frames",
        content=panel_jpeg(rgb, seed=seed),
        headers={**bearer(farm["camera"]), "Content-Type": "image/jpeg"},
    )
    assert r.status_code == 201, r.text


def test_a_task_s_life_reaches_the_receiver_signed(
    client: TestClient, admin: dict[str, str], farm: dict[str, Any]
) -> None:
    assert train(client, admin, clean_set(8)).status_code == 201
    for seed in range(4):  # dirty past the debounce: a task opens
        frame(client, farm, CLEAN_RGB + DUST, seed)
    robot = bearer(farm["robot"])
    task = client.post("/cleaning/claim", headers=robot).json()
    farm["clock"].advance(minutes=30)
    assert (
        client.post(f"/cleaning/tasks/{task['task_id']}/complete", headers=robot).status_code == 200
    )
    for seed in range(10, 14):  # still dirty after the robot: ineffective
        frame(client, farm, CLEAN_RGB + DUST, seed)

    events = client.get("/solar/events", headers=admin).json()
    assert [e["type"] for e in reversed(events)][:4] == [
        "task.opened",
        "task.claimed",
        "task.completed",
        "cleaning.ineffective",
    ]
    assert not any(e["delivered"] for e in events)  # no receiver yet: kept

    handler, got = recorder(503)  # the receiver's first answer fails: retried
    app = farm["app"]
    with served(handler) as base:
        r = client.put(
            "/solar/webhook", json={"url": f"{base}/farm", "secret": SECRET}, headers=admin
        )
        assert r.status_code == 200, r.text
        assert r.json()["signed"] is True
        timing = app.state.timing
        outbox.sweep(app.state.sessionmaker, "solar", timing)
        farm["clock"].advance(minutes=15)  # past the backoff
        outbox.sweep(app.state.sessionmaker, "solar", timing)
    bodies = [json.loads(body) for body, _ in got]
    # the first attempt of the first event failed; the others went on, then it was retried
    assert [b["type"] for b in bodies][:4] == [
        "task.opened",
        "task.claimed",
        "task.completed",
        "cleaning.ineffective",
    ]
    assert bodies[0]["data"]["panel_id"] == "p1"
    assert bodies[1]["data"]["robot_id"] == "r1"
    key = base64.b64decode(SECRET.removeprefix("whsec_"))
    for body, headers in got:
        signed = f"{headers['webhook-id']}.{headers['webhook-timestamp']}.".encode() + body
        expected = base64.b64encode(hmac.new(key, signed, hashlib.sha256).digest()).decode()
        assert headers["webhook-signature"] == f"v1,{expected}"
    assert got[0][1]["webhook-id"] == got[-1][1]["webhook-id"]  # the retry: the same message
    assert len({h["webhook-id"] for _, h in got}) == len(got) - 1
    assert all(e["delivered"] for e in client.get("/solar/events", headers=admin).json())


def test_a_baseline_too_broad_is_an_event(
    client: TestClient, admin: dict[str, str], farm: dict[str, Any]
) -> None:
    colours = [(56, 60, 84), (120, 110, 90), (30, 40, 140), (90, 140, 70), (200, 60, 60)]
    assert (
        train(
            client, admin, [panel_jpeg(np.array(c, float), seed=i) for i, c in enumerate(colours)]
        ).status_code
        == 201
    )
    [event] = client.get(
        "/solar/events", headers=admin, params={"type": "baseline.too_broad"}
    ).json()
    assert event["data"]["panel_id"] == "p1"
    assert "different panels" in event["data"]["detail"]


@pytest.mark.parametrize(
    ("body", "fault"),
    [
        ({"url": "ftp://farm.example/hook"}, "http(s)"),
        ({"url": "not a url"}, "http(s)"),
        ({"url": "https://farm.example/hook", "secret": "hunter2"}, "whsec_"),
    ],
)
def test_a_bad_webhook_is_refused_and_nothing_stored(
    client: TestClient, admin: dict[str, str], body: dict[str, str], fault: str
) -> None:
    r = client.put("/solar/webhook", json=body, headers=admin)
    assert r.status_code == 422
    assert r.json()["code"] == "bad_webhook"
    assert fault in r.json()["detail"]
    assert client.get("/solar/webhook", headers=admin).status_code == 404


def test_metrics_count_panels_by_state_and_tasks_by_outcome(
    client: TestClient, admin: dict[str, str], farm: dict[str, Any]
) -> None:
    assert client.post("/panels", json={"id": "p2"}, headers=admin).status_code == 201
    assert train(client, admin, clean_set(8)).status_code == 201
    for seed in range(4):
        frame(client, farm, CLEAN_RGB + DUST, seed)
    robot = bearer(farm["robot"])
    task = client.post("/cleaning/claim", headers=robot).json()
    r = client.post(
        f"/cleaning/tasks/{task['task_id']}/fail", json={"reason": "stuck"}, headers=robot
    )
    assert r.status_code == 200, r.text
    text = client.get("/metrics", headers=admin).text
    lines = set(text.splitlines())
    assert 'vantage_panels{state="needs_cleaning"} 1.0' in lines
    assert 'vantage_panels{state="no_baseline"} 1.0' in lines
    assert 'vantage_panels{state="clean"} 0.0' in lines
    assert 'vantage_cleaning_tasks_total{outcome="failed"} 1.0' in lines


def test_a_panel_s_history_by_hour_and_day(
    client: TestClient, admin: dict[str, str], farm: dict[str, Any]
) -> None:
    """Frames over two days, clean then dusty, at 10-minute steps (with a 20-hour gap): the
    buckets hold what the verdicts, summed here from the answers, say."""
    assert train(client, admin, clean_set(8)).status_code == 201
    clock = farm["clock"]
    verdicts = []
    for i in range(30):
        rgb = CLEAN_RGB if i < 18 else CLEAN_RGB + DUST
        if i == 12:
            clock.advance(hours=20)
        clock.advance(minutes=10)
        r = client.post(
            "/cameras/c1/frames",
            content=panel_jpeg(rgb, seed=i),
            headers={**bearer(farm["camera"]), "Content-Type": "image/jpeg"},
        )
        verdicts.append((clock.now, r.json()["verdict"]))
    for bucket, length in (("hour", 3600), ("day", 86400)):
        r = client.get("/panels/p1/history", params={"bucket": bucket}, headers=admin)
        assert r.status_code == 200, r.text
        expected: dict[int, list[dict[str, Any]]] = {}
        for at, v in verdicts:
            expected.setdefault(int(at.timestamp()) // length, []).append(v)
        got = r.json()
        assert [
            int(datetime.fromisoformat(b["start"]).timestamp()) // length for b in got
        ] == sorted(expected)
        for b in got:
            vs = expected[int(datetime.fromisoformat(b["start"]).timestamp()) // length]
            assert b["frames"] == len(vs)
            assert b["clean"] == sum(v["clean"] is True for v in vs)
            assert b["dirty"] == sum(v["clean"] is False for v in vs)
            t2 = [v["t2"] for v in vs]
            assert b["t2_mean"] == pytest.approx(np.mean(t2), rel=1e-9)
            assert b["t2_max"] == pytest.approx(max(t2), rel=1e-12)
            assert b["p_value_min"] == pytest.approx(min(v["p_value"] for v in vs), rel=1e-9)
    since = verdicts[20][0].isoformat()
    r = client.get("/panels/p1/history", params={"bucket": "day", "since": since}, headers=admin)
    assert sum(b["frames"] for b in r.json()) == 10
    assert client.get("/panels/nope/history", headers=admin).status_code == 404
    bad = client.get("/panels/p1/history", params={"bucket": "week"}, headers=admin)
    assert bad.status_code == 422


def test_a_baseline_of_photos_of_different_sizes_is_refused(
    client: TestClient, admin: dict[str, str], farm: dict[str, Any]
) -> None:
    photos = clean_set(5)
    photos[3] = panel_jpeg(CLEAN_RGB, seed=3, size=(200, 150))
    r = train(client, admin, photos)
    assert r.status_code == 422
    assert r.json()["code"] == "mixed_sizes"
    assert "clean3.jpg (200×150)" in r.json()["detail"]
    assert client.get("/panels/p1/baseline", headers=admin).status_code == 404


def test_the_retention_sweep_forgets_events_older_than_30_days(
    client: TestClient, admin: dict[str, str], farm: dict[str, Any]
) -> None:
    sessions, now = farm["app"].state.sessionmaker, farm["clock"].now
    with sessions() as session:
        outbox.enqueue(session, "solar", "task.opened", {"n": 1}, now - timedelta(days=31))
        outbox.enqueue(session, "solar", "task.opened", {"n": 2}, now - timedelta(days=29))
        session.commit()
    assert client.post("/admin/retention/sweep", headers=admin).status_code == 200
    assert [e["data"] for e in client.get("/solar/events", headers=admin).json()] == [{"n": 2}]
