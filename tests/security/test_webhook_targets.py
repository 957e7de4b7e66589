"""Webhooks must not be a way into the server's own network (SSRF) nor a port and status scanner.

Against the real app (test client) on PostgreSQL and on the embedded SQLite shape. No traffic leaves the
loopback: host names resolve through a fake resolver (tests/backend/platform_helpers.FakeDNS), the only
server ever connected to is a receiver on 127.0.0.1, and public addresses are handed out by the fake
resolver only where no connection is made."""

from __future__ import annotations

import json

import pytest

from backend.services import webhooks

from ..backend.platform_helpers import PUBLIC_TEST_IP, Api, FakeDNS, add_user, close_platform, make_platform
from .conftest import Receiver

NAMES = {
    "gis.example.com": [PUBLIC_TEST_IP],
    "gis6.example.com": ["2606:4700:4700::1111"],
    "internal.example.com": ["10.1.2.3"],
    "office.example.com": ["192.168.1.20"],
    "meta-alias.example.com": ["169.254.169.254"],
    "loop-alias.example.com": ["127.0.0.1"],
    "mixed.example.com": [PUBLIC_TEST_IP, "127.0.0.1"],           # one bad answer among good ones
    "mapped.example.com": ["::ffff:169.254.169.254"],
    "ula.example.com": ["fd12:3456::1"],
    "cgnat.example.com": ["100.64.1.1"],
}

REFUSED = [
    # loopback in every spelling resolvers accept
    "http://127.0.0.1/hook", "http://127.0.0.1:6379/", "http://localhost:8000/api/v1/health", "http://LOCALHOST./x",
    "http://foo.localhost/", "http://[::1]/", "http://[::ffff:127.0.0.1]/", "http://[::ffff:7f00:1]/",
    "http://[0:0:0:0:0:0:0:1]/", "http://2130706433/", "http://0x7f.0.0.1/", "http://0x7f000001/",
    "http://0177.0.0.1/", "http://017700000001/", "http://127.1/", "http://127.0.1/", "http://127.000.000.001/",
    "http://[2002:7f00:1::]/",                      # 6to4 wrapping 127.0.0.1
    # unspecified, private, link-local (cloud metadata), shared, multicast, broadcast, reserved
    "http://0.0.0.0:8000/", "http://0/", "http://[::]/", "http://10.0.0.5/", "http://172.16.0.1/",
    "http://192.168.1.10/", "http://169.254.169.254/latest/meta-data/", "http://100.64.0.1/",
    "http://224.0.0.1/", "http://255.255.255.255/", "http://240.0.0.1/", "http://[fe80::1]/", "http://[fc00::1]/",
    "http://[ff02::1]/", "http://[64:ff9b::a9fe:a9fe]/",
    # metadata host names, and names that resolve to internal addresses
    "http://metadata.google.internal/computeMetadata/v1/", "http://metadata/", "http://instance-data/",
    "http://internal.example.com/", "http://office.example.com/", "http://meta-alias.example.com/",
    "http://loop-alias.example.com/", "http://mixed.example.com/", "http://mapped.example.com/",
    "http://ula.example.com/", "http://cgnat.example.com/", "http://does-not-resolve.example.com/",
    # not http(s), credentials, ports
    "ftp://gis.example.com/", "file:///etc/passwd", "gopher://gis.example.com:70/", "javascript:alert(1)//x",
    "http://user:secret@gis.example.com/", "http://token@gis.example.com/", "http://gis.example.com:99999/",
    "http://gis.example.com:0/", "http://gis.example.com:-1/", "http://gis.example.com:8o/",
    # parser confusions
    "http://gis.example.com\\@127.0.0.1/", "http://gis.example.com /", "http://gis.example.com\t/x",
    "http://[fe80::1%25eth0]/",
]
ACCEPTED = ["https://gis.example.com/hooks/georef", "http://gis.example.com:8080/h?x=1",
            f"http://{PUBLIC_TEST_IP}/hook", "https://gis6.example.com/h", "https://[2606:4700:4700::1111]/h"]


@pytest.fixture(scope="module")
def admin(platform):
    add_user(platform, f"hooks-{platform.shape}@example.org", org_admin=True)
    api = Api(platform, f"hooks-{platform.shape}@example.org")
    site = api.post("/api/v1/sites", json={"name": "Hooks", "crs": "EPSG:32653"}).json()
    return api, site["id"]


@pytest.fixture
def dns(monkeypatch):
    fake = FakeDNS(NAMES)
    monkeypatch.setattr("socket.getaddrinfo", fake)
    return fake


def test_internal_targets_are_refused_at_creation(admin, dns):
    api, site_id = admin
    accepted = []
    for url in REFUSED:
        r = api.post("/api/v1/webhooks", json={"site_id": site_id, "url": url})
        if r.status_code != 422:
            accepted.append((url, r.status_code))
            continue
        assert r.headers["content-type"].startswith("application/problem+json")
        detail = r.json()["detail"]
        assert detail.startswith("url:"), (url, detail)
        # a name's resolved address is not told (that would map the internal DNS for the caller)
        for name, addrs in NAMES.items():
            if name in url:
                assert not any(a in detail for a in addrs), (url, detail)
    assert not accepted, f"internal or malformed webhook targets accepted: {accepted}"
    names = [w["url"] for w in api.get(f"/api/v1/webhooks?site_id={site_id}").json()]
    assert not set(names) & set(REFUSED)


def test_public_targets_are_accepted_and_patch_is_checked_too(admin, dns):
    api, site_id = admin
    for url in ACCEPTED:
        r = api.post("/api/v1/webhooks", json={"site_id": site_id, "url": url})
        assert r.status_code == 201, (url, r.text)
    hook = api.get(f"/api/v1/webhooks?site_id={site_id}").json()[0]
    for url in ("http://127.0.0.1:22/", "http://169.254.169.254/", "http://2130706433/", "http://meta-alias.example.com/"):
        r = api.patch(f"/api/v1/webhooks/{hook['id']}", json={"url": url})
        assert r.status_code == 422, (url, r.text)
    assert api.get(f"/api/v1/webhooks/{hook['id']}").json()["url"] == hook["url"]


def _delivery(p, site_id: str) -> str:
    with p.db().session() as s:
        msgs = webhooks.enqueue_event(s, site_id, "run.succeeded", {"run_id": "r1", "state": "succeeded"})
    assert msgs
    return msgs[-1][1]


def _hook_site(api: Api, url: str) -> tuple[str, str]:
    site = api.post("/api/v1/sites", json={"name": "Hook site", "crs": "EPSG:32653"}).json()
    r = api.post("/api/v1/webhooks", json={"site_id": site["id"], "url": url})
    assert r.status_code == 201, r.text
    return site["id"], r.json()["id"]


def test_delivery_checks_again_dns_rebinding(platform, admin, monkeypatch, receiver):
    """The name resolved to a public address when the webhook was registered, and resolves to the
    loopback (where a receiver listens) when it is delivered: the delivery is refused without a request."""
    api, _ = admin
    monkeypatch.setattr("socket.getaddrinfo", FakeDNS({"rebind.example.com": [PUBLIC_TEST_IP]}))
    site_id, hook_id = _hook_site(api, f"http://rebind.example.com:{receiver.port}/hook")
    monkeypatch.setattr("socket.getaddrinfo", FakeDNS({"rebind.example.com": ["127.0.0.1"]}))
    did = _delivery(platform, site_id)
    assert webhooks.deliver(platform.db(), did, 5, 3) == "failed"
    assert receiver.requests == []
    d = api.get(f"/api/v1/webhooks/{hook_id}/deliveries").json()[0]
    assert d["state"] == "failed" and d["status_class"] is None
    assert "127.0.0.1" not in json.dumps(d) and "refused" in d["last_error"]


def test_delivery_connects_to_the_address_it_checked(platform, admin, monkeypatch, receiver):
    """Allowed target (the loopback allowed like an on-premise network): the name is resolved once, by the
    check, and the request goes to that address with the name in Host; a client that resolved the name
    again would fail here (the second answer is 'unknown name')."""
    api, _ = admin
    first = FakeDNS({"gis.example.test": [PUBLIC_TEST_IP]})
    monkeypatch.setattr("socket.getaddrinfo", first)
    site_id, _ = _hook_site(api, f"http://gis.example.test:{receiver.port}/hook?k=1")

    class Once(FakeDNS):
        def __call__(self, host, *a, **kw):
            out = super().__call__(host, *a, **kw)
            self.names.clear()          # a second look-up of the name fails
            return out

    once = Once({"gis.example.test": ["127.0.0.1"]})
    monkeypatch.setattr("socket.getaddrinfo", once)
    did = _delivery(platform, site_id)
    assert webhooks.deliver(platform.db(), did, 5, 3, allowed_networks=["127.0.0.0/8"]) == "delivered"
    assert once.asked == ["gis.example.test"]
    assert len(receiver.requests) == 1
    req = receiver.requests[0]
    assert req["path"] == "/hook?k=1"
    assert req["headers"]["Host"] == f"gis.example.test:{receiver.port}"
    assert json.loads(req["body"])["event"] == "run.succeeded"


@pytest.mark.parametrize("status,transient,state", [(500, True, "pending"), (404, False, "failed"),
                                                    (302, False, "failed")])
def test_delivery_log_is_not_a_scanner(platform, admin, monkeypatch, status, transient, state):
    """What the deliveries endpoint shows: a status class and a generic reason, never the receiver's body,
    the exact code, nor the network error's text; redirects are not followed."""
    api, _ = admin
    rec = Receiver(status, {"Location": "http://169.254.169.254/latest/meta-data/"} if status == 302 else None)
    try:
        monkeypatch.setattr("socket.getaddrinfo", FakeDNS({"gis.example.test": [PUBLIC_TEST_IP]}))
        site_id, hook_id = _hook_site(api, f"http://gis.example.test:{rec.port}/h")
        monkeypatch.setattr("socket.getaddrinfo", FakeDNS({"gis.example.test": ["127.0.0.1"]}))
        did = _delivery(platform, site_id)
        if transient:
            with pytest.raises(webhooks.TransientDeliveryError):
                webhooks.deliver(platform.db(), did, 5, 3, allowed_networks=["127.0.0.0/8"])
        else:
            assert webhooks.deliver(platform.db(), did, 5, 3, allowed_networks=["127.0.0.0/8"]) == "failed"
        assert len(rec.requests) == 1          # a redirect is not followed
        d = api.get(f"/api/v1/webhooks/{hook_id}/deliveries").json()[0]
        assert d["state"] == state
        assert d["status_class"] == f"{status // 100}xx"
        assert "last_status" not in d
        text = json.dumps(d)
        assert "SECRET" not in text and "nginx" not in text and "169.254" not in text
        assert str(status) not in d["last_error"] and d["last_error"] in (
            webhooks.REASON_SERVER, webhooks.REASON_REJECTED, webhooks.REASON_REDIRECT)
    finally:
        rec.close()


def test_connection_errors_are_generic(platform, admin, monkeypatch):
    """A closed port and an open one look alike in the log ('connection failed', no errno, no text)."""
    import socket

    api, _ = admin
    with socket.socket() as sk:                    # a port nobody listens on
        sk.bind(("127.0.0.1", 0))
        closed = sk.getsockname()[1]
    monkeypatch.setattr("socket.getaddrinfo", FakeDNS({"gis.example.test": [PUBLIC_TEST_IP]}))
    site_id, hook_id = _hook_site(api, f"http://gis.example.test:{closed}/h")
    monkeypatch.setattr("socket.getaddrinfo", FakeDNS({"gis.example.test": ["127.0.0.1"]}))
    did = _delivery(platform, site_id)
    with pytest.raises(webhooks.TransientDeliveryError):
        webhooks.deliver(platform.db(), did, 5, 3, allowed_networks=["127.0.0.0/8"])
    d = api.get(f"/api/v1/webhooks/{hook_id}/deliveries").json()[0]
    assert d["last_error"] == webhooks.REASON_CONNECT
    assert "rrno" not in d["last_error"] and "efused" not in d["last_error"]


@pytest.fixture(scope="module")
def onprem(tmp_path_factory):
    """An embedded platform whose operator allows one private network (an on-premise GIS server)."""
    p = make_platform(tmp_path_factory.mktemp("onprem"), "embedded", webhook_allowed_networks="10.20.0.0/16")
    yield p
    close_platform(p)


def test_operator_allow_list(onprem, monkeypatch):
    add_user(onprem, "onprem@example.org", org_admin=True)
    api = Api(onprem, "onprem@example.org")
    site = api.post("/api/v1/sites", json={"name": "On-prem", "crs": "EPSG:32653"}).json()
    monkeypatch.setattr("socket.getaddrinfo", FakeDNS({"gis.corp.example": ["10.20.3.4"],
                                                       "other.corp.example": ["10.30.3.4"]}))
    for url in ("http://10.20.3.4:8080/hook", "https://gis.corp.example/hook"):
        r = api.post("/api/v1/webhooks", json={"site_id": site["id"], "url": url})
        assert r.status_code == 201, (url, r.text)
    # the allow list opens that network only, and never the spellings that hide an address
    for url in ("http://10.30.3.4/", "http://other.corp.example/", "http://127.0.0.1/", "http://169.254.169.254/",
                "http://012.20.3.4/", "http://169090052/", "http://localhost/"):
        r = api.post("/api/v1/webhooks", json={"site_id": site["id"], "url": url})
        assert r.status_code == 422, (url, r.text)
