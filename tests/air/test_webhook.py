"""Alert delivery against real receivers on a local socket: only a 2xx answer to the POST is a
delivery, a bad answer is one alert's failed attempt, and retries go on for the retry period."""

from __future__ import annotations

import base64
import contextlib
import json
import socket
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from datetime import UTC, datetime, timedelta
from http.server import BaseHTTPRequestHandler
from typing import Any

import pytest
import standardwebhooks
from fastapi.testclient import TestClient
from pydantic import ValidationError
from sqlalchemy import Engine, select
from sqlalchemy.orm import Session, sessionmaker

from app.air.models import AirAlert
from app.air.services import webhook as alert_webhook
from app.platform import webhooks
from app.platform.db.models import Camera
from app.platform.db.session import make_engine, make_sessionmaker
from app.platform.settings import Settings
from app.platform.timing import Timing
from tests.factories import recorder, served
from tests.factories.air import T0, calibrate, seed_alerts, sky_jpeg


def at(now: datetime) -> Timing:
    """Timing whose clock stands at ``now``."""
    return Timing(clock=lambda: now)


def state(engine: Engine) -> dict[str, tuple[bool, int, str | None]]:
    with Session(engine) as s:
        return {a.id: (a.delivered, a.attempts, a.last_error) for a in s.scalars(select(AirAlert))}


@pytest.fixture
def sessions(database_url: str) -> Iterator[sessionmaker[Session]]:
    engine = make_engine(database_url)
    try:
        yield make_sessionmaker(engine)
    finally:
        engine.dispose()


def test_a_redirect_is_not_a_delivery(engine: Engine, sessions: sessionmaker[Session]) -> None:
    """An http:// hook that moved to https:// answers 301. Followed, urllib would send a GET
    without the alert, and a page answering it 200 would have counted as delivered."""
    seen: list[tuple[str, str]] = []

    class Moved(BaseHTTPRequestHandler):
        def do_POST(self) -> None:  # noqa: N802
            self.rfile.read(int(self.headers["Content-Length"]))
            seen.append(("POST", self.path))
            self.send_response(301)
            self.send_header("Location", "/landing")
            self.end_headers()

        def do_GET(self) -> None:  # noqa: N802
            seen.append(("GET", self.path))
            self.send_response(200)
            self.end_headers()

        def log_message(self, *args: Any) -> None:
            pass

    seed_alerts(engine, 1)
    with served(Moved) as base:
        assert alert_webhook.sweep(sessions, f"{base}/hook", at(T0)) == 0
    assert seen == [("POST", "/hook")]
    delivered, attempts, error = state(engine)["a0"]
    assert (delivered, attempts) == (False, 1)
    assert "301 redirect to '/landing'" in str(error)


def raw_receiver(answer: Callable[[str], bytes]) -> tuple[socket.socket, str]:
    """A TCP server reading one request per connection and sending ``answer(alert_id)``."""
    listener = socket.create_server(("127.0.0.1", 0))

    def loop() -> None:
        while True:
            try:
                conn, _ = listener.accept()
            except OSError:
                return
            with conn:
                data = b""
                while b"\r\n\r\n" not in data:
                    data += conn.recv(65536)
                head, _, body = data.partition(b"\r\n\r\n")
                length = int(next(
                    line.split(b":")[1] for line in head.split(b"\r\n")
                    if line.lower().startswith(b"content-length")
                ))  # fmt: skip
                while len(body) < length:
                    body += conn.recv(65536)
                conn.sendall(answer(json.loads(body)["alert_id"]))

    threading.Thread(target=loop, daemon=True).start()
    return listener, f"http://127.0.0.1:{listener.getsockname()[1]}/hook"


def test_an_answer_that_is_not_http_fails_that_alert_only(
    engine: Engine, sessions: sessionmaker[Session]
) -> None:
    """A proxy that cuts one answer (or something not HTTP on the port) made the whole sweep
    raise before: its transaction rolled back, the alerts already delivered were sent again
    at every sweep, and the failing one was retried every few seconds without an error."""
    answers = {
        "a0": b"HTTP/1.1 204 No Content\r\n\r\n",
        "a1": b"-ERR unknown command\r\n",
        "a2": b"HTTP/1.1 204 No Content\r\n\r\n",
    }
    posted: list[str] = []

    def answer(alert_id: str) -> bytes:
        posted.append(alert_id)
        return answers[alert_id]

    seed_alerts(engine, 3)
    listener, url = raw_receiver(answer)
    try:
        assert alert_webhook.sweep(sessions, url, at(T0)) == 2
        after = state(engine)
        assert {k: v[:2] for k, v in after.items()} == {
            "a0": (True, 1),
            "a1": (False, 1),
            "a2": (True, 1),
        }
        assert "BadStatusLine" in str(after["a1"][2])
        # the next sweep, once a1's backoff has passed, tries a1 alone
        assert alert_webhook.sweep(sessions, url, at(T0 + timedelta(seconds=3))) == 0
    finally:
        listener.close()
    assert posted == ["a0", "a1", "a2", "a1"]


def test_a_receiver_sending_its_answer_a_byte_at_a_time_fails_at_the_deadline(
    engine: Engine, sessions: sessionmaker[Session], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Each read waits at most TIMEOUT_S, and a receiver sending a byte every few seconds
    never let one run out: a POST was still waiting after 50 s, and the sweep with it (no
    later alert went anywhere). And once cut, what had come passed for a whole answer 200.
    The POST now fails at DEADLINE_S (1 s here), and the sweep goes on to the next alert."""
    monkeypatch.setattr(webhooks, "DEADLINE_S", 1.0)
    listener = socket.create_server(("127.0.0.1", 0))
    stop = threading.Event()

    def trickle() -> None:
        while not stop.is_set():
            try:
                conn, _ = listener.accept()
            except OSError:
                return
            with conn:
                conn.recv(65536)
                with contextlib.suppress(OSError):
                    conn.sendall(b"HTTP/1.1 204 No Content\r\n")
                    while not stop.wait(0.2):
                        conn.sendall(b"X")

    threading.Thread(target=trickle, daemon=True).start()
    seed_alerts(engine, 2)
    result: list[int] = []
    url = f"http://127.0.0.1:{listener.getsockname()[1]}/hook"
    sweeping = threading.Thread(
        target=lambda: result.append(alert_webhook.sweep(sessions, url, at(T0)))
    )
    try:
        sweeping.start()
        sweeping.join(timeout=15)
        assert not sweeping.is_alive(), "the sweep is still posting"
    finally:
        stop.set()
        listener.close()
    assert result == [0]
    after = state(engine)
    assert {k: v[:2] for k, v in after.items()} == {"a0": (False, 1), "a1": (False, 1)}
    assert all("no whole answer within 1 s" in str(v[2]) for v in after.values())


def closed_port() -> str:
    with socket.create_server(("127.0.0.1", 0)) as s:
        return f"http://127.0.0.1:{s.getsockname()[1]}/hook"


def test_retries_back_off_up_to_ten_minutes_apart_for_the_retry_period(
    engine: Engine, sessions: sessionmaker[Session]
) -> None:
    """A receiver down for hours (nothing listens on the port) still gets the alert when it is
    back; after the retry period the alert is given up. Before, the sixth failure (62 s after
    the first) was the last."""
    seed_alerts(engine, 1)
    url = closed_port()
    now = T0
    times = []
    while now < T0 + timedelta(hours=2):
        with Session(engine) as s:
            due = s.get(AirAlert, "a0")
            assert due is not None
            now = max(now, due.next_attempt_at or now)
        alert_webhook.sweep(sessions, url, at(now), retry_for=timedelta(hours=3))
        times.append(now)
    gaps = [(b - a).total_seconds() for a, b in zip(times, times[1:], strict=False)]
    assert gaps[:9] == [2, 4, 8, 16, 32, 64, 128, 256, 512]
    assert set(gaps[9:]) == {600}
    assert state(engine)["a0"][:2] == (False, len(times))
    with Session(engine) as s:
        alert = s.get(AirAlert, "a0")
        assert alert is not None
        assert alert_webhook.delivery(
            alert, T0 + timedelta(hours=2), retry_for=timedelta(hours=3)
        ) == ("pending")
        assert alert_webhook.delivery(
            alert, T0 + timedelta(hours=4), retry_for=timedelta(hours=3)
        ) == ("gave_up")
        assert alert_webhook.delivery(alert, T0, retry_for=None) == "no_webhook"
    # past the retry period the sweep leaves it alone
    late = T0 + timedelta(hours=3, seconds=1)
    alert_webhook.sweep(sessions, url, at(late), retry_for=timedelta(hours=3))
    assert state(engine)["a0"][1] == len(times)


@pytest.mark.parametrize("url", ["hooks.example.org/alerts", "ftp://example.org/x", "http://"])
def test_a_webhook_url_that_cannot_be_posted_to_is_refused_at_start(url: str) -> None:
    with pytest.raises(ValidationError, match="VANTAGE_ALERT_WEBHOOK_URL"):
        Settings(alert_webhook_url=url)


def test_a_process_dying_mid_sweep_keeps_the_deliveries_before(
    engine: Engine, sessions: sessionmaker[Session], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The process stops (here SystemExit) while posting the second alert: the first, already
    taken by the receiver, stays delivered (one transaction for the whole sweep rolled it back,
    and it was sent again). The second, claimed, may have reached the receiver: it is sent
    again once its claim has run out, the third with it."""
    posted: list[str] = []

    def post(url: str, body: bytes, headers: dict[str, str]) -> None:
        posted.append(json.loads(body)["alert_id"])
        if len(posted) == 2:
            raise SystemExit

    seed_alerts(engine, 3)
    monkeypatch.setattr(webhooks, "post", post)
    with pytest.raises(SystemExit):
        alert_webhook.sweep(sessions, "http://hook", at(T0))
    assert {k: v[:2] for k, v in state(engine).items()} == {
        "a0": (True, 1),
        "a1": (False, 1),
        "a2": (False, 0),
    }
    monkeypatch.undo()
    receiver, got = recorder()
    with served(receiver) as url:
        assert (
            alert_webhook.sweep(sessions, url, at(T0 + alert_webhook.CLAIM - timedelta(seconds=1)))
            == 1
        )
        assert [json.loads(b)["alert_id"] for b, _ in got] == ["a2"]  # a1 still claimed
        assert alert_webhook.sweep(sessions, url, at(T0 + alert_webhook.CLAIM)) == 1
    assert [json.loads(b)["alert_id"] for b, _ in got] == ["a2", "a1"]
    assert {k: v[:2] for k, v in state(engine).items()} == {
        "a0": (True, 1),
        "a1": (True, 2),
        "a2": (True, 1),
    }


def test_the_signature_of_the_standard_webhooks_example() -> None:
    """The example of the Standard Webhooks specification (secret, id, timestamp, body and the
    signature its reference library, standardwebhooks 1.1.0, computes for them)."""
    key = webhooks.signing_key("whsec_MfKQ9r8GKYqrTwjUPD8ILPZIo2LaLaSw")
    got = webhooks.signature(
        key, "msg_p5jXN8AQM9LWM0D4loKWxJek", 1614265330, b'{"test": 2432232314}'
    )
    assert got == "v1,g0hM9SsE+OTPJTGt/tmIKtSyZlE3uFJELVlNIOLJ1OE="


@pytest.mark.parametrize(
    ("secret", "why"),
    [
        ("whsec_not base64!", "base64"),
        ("whsec_" + "QUJD", "3"),  # 3 bytes
        ("whsec_" + "A" * 100, "75"),  # 75 bytes
    ],
)
def test_a_secret_that_is_not_a_standard_webhooks_one_is_refused_at_start(
    secret: str, why: str
) -> None:
    with pytest.raises(ValidationError, match=f"VANTAGE_ALERT_WEBHOOK_SECRET: .*{why}"):
        Settings(alert_webhook_url="http://hook.example/", alert_webhook_secret=secret)


def test_alerts_are_signed_and_say_where_and_when(
    engine: Engine, sessions: sessionmaker[Session]
) -> None:
    """A receiver checks each POST with a Standard Webhooks library (the reference one, not
    this service's code): signed with the secret, and one tampered with is refused. The id is
    the alert's on every attempt, so a receiver drops a repeat; the body names the camera's
    place and when the frame was taken."""
    secret = "whsec_" + base64.b64encode(bytes(range(32))).decode()
    receiver_class, got = recorder(500)
    seed_alerts(engine, 1)
    with Session(engine) as s:
        camera = s.get(Camera, "sky")
        assert camera is not None
        camera.name, camera.lat, camera.lon = "Piazza Duomo", 45.464, 9.19
        s.commit()
    now = datetime.now(UTC)  # receivers refuse a timestamp more than 5 minutes off
    old = now - T0 + timedelta(days=1)  # the alerts were raised at T0: retried till now
    key = webhooks.signing_key(secret)
    with served(receiver_class) as base:
        for t, delivered in ((now, 0), (now + timedelta(seconds=3), 1)):  # 500, then 204
            sent = alert_webhook.sweep(sessions, f"{base}/hook", at(t), key=key, retry_for=old)
            assert sent == delivered
    receiver = standardwebhooks.Webhook(secret)
    for body, headers in got:
        alert = receiver.verify(body, headers)
        assert headers["webhook-id"] == alert["alert_id"] == "a0"
        assert alert["kind"] == "raised"
        assert {k: alert[k] for k in ("camera_name", "lat", "lon", "captured_at")} == {
            "camera_name": "Piazza Duomo",
            "lat": 45.464,
            "lon": 9.19,
            "captured_at": T0.isoformat(),
        }
    assert [int(h["webhook-timestamp"]) for _, h in got] == [
        int(now.timestamp()),
        int(now.timestamp()) + 3,
    ]
    body, headers = got[0]
    with pytest.raises(standardwebhooks.webhooks.WebhookVerificationError):
        receiver.verify(body.replace(b'"Poor"', b'"Good"'), headers)
    with pytest.raises(standardwebhooks.webhooks.WebhookVerificationError):
        standardwebhooks.Webhook("whsec_" + base64.b64encode(bytes(32)).decode()).verify(
            body, headers
        )


def test_unsigned_without_a_secret(engine: Engine, sessions: sessionmaker[Session]) -> None:
    receiver_class, got = recorder()
    seed_alerts(engine, 1)
    with served(receiver_class) as base:
        assert alert_webhook.sweep(sessions, f"{base}/hook", at(T0)) == 1
    headers = got[0][1]
    assert headers["webhook-id"] == "a0"
    assert "webhook-signature" not in headers


def test_a_receiver_slow_to_answer_holds_no_database_connection(
    engine: Engine, sessions: sessionmaker[Session], monkeypatch: pytest.MonkeyPatch
) -> None:
    """While a POST waits for the receiver, the database serves everyone else. The sweep's
    engine is the service's: with SQLite, one connection for every request. A sweep that held
    its transaction through the POST held the whole service for as long, up to ``TIMEOUT_S``
    an alert (GET /cameras waited 20 s behind 4 alerts to a receiver that never answered)."""
    wait = 20.0
    seed_alerts(engine, 1)
    posting, answer = threading.Event(), threading.Event()

    def post(url: str, body: bytes, headers: dict[str, str]) -> None:
        posting.set()
        answer.wait(2 * wait)

    def alerts_pending() -> int:
        with sessions() as s:
            return len(s.scalars(select(AirAlert).where(AirAlert.delivered.is_(False))).all())

    monkeypatch.setattr(webhooks, "post", post)
    with ThreadPoolExecutor(2) as pool:
        sweep = pool.submit(alert_webhook.sweep, sessions, "http://hook", at(T0))
        try:
            assert posting.wait(wait)
            assert pool.submit(alerts_pending).result(timeout=wait) == 1
            assert not sweep.done()
        finally:
            answer.set()
        assert sweep.result(timeout=wait) == 1
    assert state(engine)["a0"] == (True, 1, None)


def test_an_alert_posted_late_in_a_long_sweep_is_not_due_for_another_process(
    engine: Engine, sessions: sessionmaker[Session], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A sweep of many alerts to a slow receiver takes minutes. Each alert is claimed from the
    time it is posted, not from the sweep's start: a claim dated from the start ran out before
    the later alerts were posted, and another process's sweep would send them too."""
    seed_alerts(engine, 3)
    clock = [T0]
    due_elsewhere = []

    def post(url: str, body: bytes, headers: dict[str, str]) -> None:
        clock[0] += timedelta(minutes=1)  # a slow receiver: each POST takes a minute
        alert_id = json.loads(body)["alert_id"]
        with Session(engine) as s:
            alert = s.get(AirAlert, alert_id)
            assert alert is not None
            assert alert.next_attempt_at is not None
            due_elsewhere.append(alert.next_attempt_at <= clock[0])

    monkeypatch.setattr(webhooks, "post", post)
    assert alert_webhook.sweep(sessions, "http://hook", Timing(clock=lambda: clock[0])) == 3
    assert due_elsewhere == [False, False, False]


def test_a_name_server_that_does_not_answer_fails_the_post_in_time(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The receiver's name is looked up within TIMEOUT_S (0.5 s here) too. Before, the lookup
    was bounded by the resolver alone (by glibc's documented defaults, up to 30 s with three
    silent name servers), beyond the POST's deadline, and held the sweep as long. Here the lookup of
    ``hooks.example`` never answers until the test ends; the POST fails within seconds, and
    nothing is sent when the answer comes after all."""
    monkeypatch.setattr(webhooks, "TIMEOUT_S", 0.5)
    real = socket.getaddrinfo
    released = threading.Event()
    receiver_class, got = recorder()

    def silent(host: Any, *args: Any, **kwargs: Any) -> Any:
        if host == "hooks.example":
            released.wait(30)
            return real("127.0.0.1", *args, **kwargs)
        return real(host, *args, **kwargs)

    monkeypatch.setattr(socket, "getaddrinfo", silent)
    with served(receiver_class) as base:
        port = base.rsplit(":", 1)[1]
        with ThreadPoolExecutor(1) as pool:
            url = f"http://hooks.example:{port}/h"
            posting = pool.submit(webhooks.send_test, url, T0, key=None)
            try:
                _, error = posting.result(timeout=10)
            finally:
                released.set()
        assert error is not None
        assert "no address for 'hooks.example' within 0.5 s" in error
        time.sleep(0.2)  # the lookup answered: still nothing is sent
        assert got == []
        # a name that does answer is posted to, trying its addresses in the resolver's order
        # (localhost may come as ::1 first, where nothing listens)
        _, error = webhooks.send_test(f"http://localhost:{port}/h", T0, key=None)
        assert error is None
        assert len(got) == 1


def deliveries(client: TestClient, admin: dict[str, str]) -> dict[str, float]:
    """``vantage_alert_deliveries_total`` by outcome, as /metrics gives it."""
    from prometheus_client.parser import text_string_to_metric_families

    text = client.get("/metrics", headers=admin).text
    return {
        s.labels["outcome"]: s.value
        for family in text_string_to_metric_families(text)
        for s in family.samples
        if s.name == "vantage_alert_deliveries_total"
    }


def test_alert_webhook_retries_until_delivered(settings: Any, engine: Any) -> None:
    """The first POST fails (HTTP 500); the retry after the backoff is delivered, signed with
    the configured secret (checked with the Standard Webhooks reference library)."""
    import threading
    import time
    from http.server import BaseHTTPRequestHandler, HTTPServer

    import standardwebhooks
    from pydantic import SecretStr

    from app.main import create_app
    from tests.factories import empty_tables

    secret = "whsec_" + "c2lnbmluZyBrZXkgb2YgdGhlIGNpdHkncyBhbGVydHM="  # 32 bytes
    verify = standardwebhooks.Webhook(secret).verify
    received: list[dict[str, Any]] = []

    class Hook(BaseHTTPRequestHandler):
        def do_POST(self) -> None:  # noqa: N802
            body = self.rfile.read(int(self.headers["Content-Length"]))
            received.append(verify(body, dict(self.headers.items())))
            self.send_response(500 if len(received) == 1 else 204)
            self.end_headers()

        def log_message(self, *args: Any) -> None:
            pass

    server = HTTPServer(("127.0.0.1", 0), Hook)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    empty_tables(engine)
    app = create_app(
        settings.model_copy(
            update={
                "alert_webhook_url": f"http://127.0.0.1:{server.server_port}/hook",
                "alert_poll_seconds": 0.05,
                "alert_webhook_secret": SecretStr(secret),
            }
        )
    )
    admin = {"Authorization": f"Bearer {settings.admin_token.get_secret_value()}"}
    try:
        with TestClient(app) as client:
            before = deliveries(client, admin)
            token = client.post(
                "/cameras", json={"id": "s", "kind": "sky", "roi": [0, 0, 160, 55]}, headers=admin
            ).json()["token"]
            assert calibrate(client, admin, camera="s").status_code == 201
            for k in range(3):
                client.post(
                    "/cameras/s/frames",
                    content=sky_jpeg(1, seed=k),
                    headers={"Authorization": f"Bearer {token}", "Content-Type": "image/jpeg"},
                )
            deadline = time.monotonic() + 15
            while time.monotonic() < deadline:
                alerts = client.get("/air/alerts").json()
                if alerts and alerts[0]["delivered"]:
                    break
                time.sleep(0.1)
            assert alerts[0]["delivered"] is True
            assert alerts[0]["attempts"] == 2
            assert alerts[0]["delivery"] == "delivered"
            assert alerts[0]["last_error"] is None
            # what an operator alerts on: the receiver failing (a counter per outcome)
            after = deliveries(client, admin)
            assert {k: after[k] - before.get(k, 0.0) for k in after} == {
                "failed": 1.0,
                "delivered": 1.0,
            }
    finally:
        server.shutdown()
        server.server_close()
    assert len(received) == 2
    assert received[1]["message"].startswith("Today's Air Quality is")


def test_a_test_alert_checks_the_receiver_and_its_secret(
    client: TestClient, settings: Any, engine: Any, admin: dict[str, str]
) -> None:
    """``POST /air/alerts/test``: the operator checks the receiver (and that it verifies the
    signature) before the air turns Poor. Nothing is recorded; without a webhook, 409."""
    import threading
    from http.server import BaseHTTPRequestHandler, HTTPServer

    import standardwebhooks
    from pydantic import SecretStr

    from app.main import create_app

    assert client.post("/air/alerts/test", headers=admin).status_code == 409
    secret = "whsec_" + "dGhlIGNpdHkncyB0ZXN0IHNpZ25pbmcga2V5IDMyYg=="
    got: list[dict[str, Any]] = []
    answers = [204, 500]

    class Hook(BaseHTTPRequestHandler):
        def do_POST(self) -> None:  # noqa: N802
            body = self.rfile.read(int(self.headers["Content-Length"]))
            got.append(standardwebhooks.Webhook(secret).verify(body, dict(self.headers.items())))
            self.send_response(answers[len(got) - 1])
            self.end_headers()

        def log_message(self, *args: Any) -> None:
            pass

    server = HTTPServer(("127.0.0.1", 0), Hook)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    app = create_app(
        settings.model_copy(
            update={
                "alert_webhook_url": f"http://127.0.0.1:{server.server_port}/hook",
                "alert_webhook_secret": SecretStr(secret),
            }
        )
    )
    try:
        with TestClient(app) as hooked:
            r = hooked.post("/air/alerts/test", headers=admin)
            assert r.status_code == 200, r.text
            assert r.json() == {
                "webhook_id": got[0]["alert_id"],
                "delivered": True,
                "error": None,
                "signed": True,
            }
            assert got[0]["kind"] == "test"
            failed = hooked.post("/air/alerts/test", headers=admin).json()
            assert (failed["delivered"], failed["error"]) == (
                False,
                "HTTP 500 Internal Server Error",
            )
            assert hooked.get("/air/alerts").json() == []
            camera = hooked.post("/cameras", json={"id": "s", "kind": "sky"}, headers=admin)
            as_camera = {"Authorization": f"Bearer {camera.json()['token']}"}
            assert hooked.post("/air/alerts/test", headers=as_camera).status_code == 403
    finally:
        server.shutdown()
        server.server_close()
