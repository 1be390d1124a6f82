"""The secure bus on loopback: the shipped router config (deploy/zenohd.json5: mutual TLS,
access control) with certificates from ``robocal certs``; real Zenoh sessions per role."""

import json
import os
import stat
import time
from pathlib import Path

import pytest
import zenoh

from kinematics.errors import ConfigError
from stream.bus import BusConfig, TlsConfig, free_port, open_session, publisher
from stream.router import open_router, router_config
from stream.security import ROLES, make_line_certs, parse_roles

pytestmark = pytest.mark.integration
ROUTER_CONFIG = Path(__file__).resolve().parents[2] / "deploy" / "zenohd.json5"
SETTLE_S = 0.5  # declarations reach the router; a dropped message would have arrived by then


@pytest.fixture(scope="module")
def line(tmp_path_factory):
    """A router from the shipped config and a function that opens a session of a role."""
    certs = tmp_path_factory.mktemp("certs")
    make_line_certs(certs, (*ROLES, "compensation-plc2"))
    port = free_port()
    router = open_router(router_config(ROUTER_CONFIG, (f"tls/127.0.0.1:{port}",), certs))
    opened = []

    def session(role: str) -> zenoh.Session:
        tls = TlsConfig(
            ca=str(certs / "ca.pem"),
            cert=str(certs / f"{role}.pem"),
            key=str(certs / f"{role}.key"),
        )
        s = open_session(BusConfig.loopback(port, listen=False, tls=tls))
        opened.append(s)
        return s

    yield session, port, certs
    for s in opened:
        s.close()
    router.close()


def _client_config(port: int, tls: dict) -> zenoh.Config:
    zc = zenoh.Config()
    zc.insert_json5("mode", '"client"')
    zc.insert_json5("scouting/multicast/enabled", "false")
    zc.insert_json5("connect/endpoints", json.dumps([f"tls/127.0.0.1:{port}"]))
    zc.insert_json5("transport/link/tls", json.dumps(tls))
    return zc


def _received(
    sub_session: zenoh.Session, key: str, publishers: dict[str, zenoh.Session], last: str
):
    """What a subscriber on ``key`` receives when each role puts its name there, ``last`` last."""
    got: list[str] = []
    sub = sub_session.declare_subscriber(key, lambda s: got.append(s.payload.to_string()))
    time.sleep(SETTLE_S)
    for role, s in publishers.items():
        if role != last:
            s.put(key, role)
    publishers[last].put(key, last)
    deadline = time.monotonic() + 10
    while last not in got and time.monotonic() < deadline:
        time.sleep(0.02)
    time.sleep(SETTLE_S)
    sub.undeclare()
    return got


def test_a_session_without_a_certificate_or_with_a_foreign_one_cannot_connect(line, tmp_path):
    _, port, certs = line
    with pytest.raises(zenoh.ZError):  # trusts the router, shows no certificate
        zenoh.open(_client_config(port, {"root_ca_certificate": str(certs / "ca.pem")}))
    rogue = make_line_certs(tmp_path / "rogue", ("tracker",))  # same role name, another CA
    forged = {
        "root_ca_certificate": str(certs / "ca.pem"),
        "connect_certificate": str(rogue.roles["tracker"][0]),
        "connect_private_key": str(rogue.roles["tracker"][1]),
        "enable_mtls": True,
    }
    with pytest.raises(zenoh.ZError):
        zenoh.open(_client_config(port, forged))
    plain = zenoh.Config()  # plain TCP to the TLS port
    plain.insert_json5("mode", '"client"')
    plain.insert_json5("scouting/multicast/enabled", "false")
    plain.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    with pytest.raises(zenoh.ZError):
        zenoh.open(plain)


@pytest.mark.parametrize("stream, owner", [("tracker", "tracker"), ("model", "learner")])
def test_only_the_owning_role_publishes_on_its_stream(line, stream, owner):
    """Only the tracker role injects tracker samples; only the learner publishes models."""
    session, _, _ = line
    roles = ("robot", "tracker", "daq", "learner", "dashboard", "compensation")
    publishers = {r: session(r) for r in roles}
    got = _received(session("dashboard"), f"robocal/c1/r1/{stream}", publishers, owner)
    assert got == [owner]


def test_only_listed_clients_query_compensate(line):
    session, _, _ = line
    server = session("learner")
    queryable = server.declare_queryable(
        "robocal/c1/r1/compensate", lambda q: q.reply("robocal/c1/r1/compensate", b"answer")
    )
    time.sleep(SETTLE_S)

    def answers(role: str) -> list[bytes]:
        replies = session(role).get("robocal/c1/r1/compensate", timeout=2.0)
        return [r.ok.payload.to_bytes() for r in replies if r.ok is not None]

    assert answers("compensation") == [b"answer"]
    for role in ("robot", "tracker", "dashboard", "compensation-plc2"):  # plc2: not in the list
        assert answers(role) == [], role
    queryable.undeclare()


def test_only_the_learner_answers_compensate_and_model_queries(line):
    """A rogue service (any other role) cannot answer with forged corrections or models."""
    session, _, _ = line
    rogues = [session(r) for r in ("robot", "tracker", "daq", "dashboard", "compensation")]
    learner = session("learner")
    declared = []
    for stream in ("compensate", "model"):
        k = f"robocal/c1/r1/{stream}"
        for s in rogues:
            declared.append(s.declare_queryable(k, lambda q, k=k: q.reply(k, b"forged")))
        declared.append(learner.declare_queryable(k, lambda q, k=k: q.reply(k, b"genuine")))
    time.sleep(SETTLE_S)
    for stream, asker in (("compensate", "compensation"), ("model", "dashboard")):
        replies = session(asker).get(
            f"robocal/c1/r1/{stream}",
            target=zenoh.QueryTarget.ALL,
            consolidation=zenoh.ConsolidationMode.NONE,  # every answer, not one per key
            timeout=2.0,
        )
        assert [r.ok.payload.to_bytes() for r in replies if r.ok is not None] == [b"genuine"]
    for q in declared:
        q.undeclare()


def test_certs_are_signed_by_one_ca_with_owner_only_keys(tmp_path):
    from cryptography import x509

    certs = make_line_certs(tmp_path, ("learner", "router"), hosts=("10.1.2.3",))
    ca = x509.load_pem_x509_certificate(certs.ca.read_bytes())
    for role, (cert, key) in certs.roles.items():
        c = x509.load_pem_x509_certificate(cert.read_bytes())
        c.verify_directly_issued_by(ca)
        assert c.subject.rfc4514_string() == f"CN={role}"
        assert stat.S_IMODE(os.stat(key).st_mode) == 0o600
    assert stat.S_IMODE(os.stat(certs.ca_key).st_mode) == 0o600
    router = x509.load_pem_x509_certificate(certs.roles["router"][0].read_bytes())
    san = router.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert {str(ip) for ip in san.get_values_for_type(x509.IPAddress)} == {"127.0.0.1", "10.1.2.3"}
    with pytest.raises(ConfigError, match="never overwritten"):
        make_line_certs(tmp_path, ("learner",))
    again = make_line_certs(tmp_path, ("daq",))  # the CA is reused
    assert again.ca.read_bytes() == certs.ca.read_bytes()


@pytest.mark.parametrize("text", ["", "learner,learner", "admin", "Learner", "tracker-"])
def test_bad_role_lists_are_refused(text):
    with pytest.raises(ConfigError):
        parse_roles(text)


TLS = {"ca": "a", "cert": "b", "key": "c"}


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"mode": "client", "connect": ("tcp/127.0.0.1:7447",), "tls": TLS}, "tls/"),
        ({"connect": ("tls/127.0.0.1:7447",)}, "tls/"),
        ({"mode": "client", "tls": {"ca": "a", "cert": "b"}}, "needs ca, cert and key"),
        ({"connect": ("tls/127.0.0.1:7447",), "tls": TLS}, "mode = 'client'"),  # a peer
        ({"mode": "client", "listen": ("tls/127.0.0.1:1",), "tls": TLS}, "no listen"),
        ({"zenoh_config": "z.json5", "mode": "client"}, "leave the other bus keys"),
    ],
)
def test_bus_tls_config_is_checked(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        BusConfig(**kwargs)


def test_unreadable_certificate_is_one_clear_error(tmp_path):
    tls = TlsConfig(ca=str(tmp_path / "ca.pem"), cert="x.pem", key="x.key")
    with pytest.raises(ConfigError, match=r"bus\.tls\.ca: cannot read"):
        open_session(BusConfig.loopback(free_port(), listen=False, tls=tls))


def test_robocal_certs_writes_a_line_and_refuses_bad_roles_in_one_line(tmp_path, capsys):
    from stream.cli import main

    out = tmp_path / "line"
    assert main(["certs", "--out", str(out), "--roles", "learner,router", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert set(result["roles"]) == {"learner", "router"} and Path(result["ca"]).exists()
    assert main(["certs", "--out", str(out), "--roles", "learner,root"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "bad: ['root']" in err[0]


def test_a_zenoh_config_file_joins_the_secure_bus(line, tmp_path):
    session, port, certs = line
    cfg = tmp_path / "learner.json5"
    tls = {
        "root_ca_certificate": str(certs / "ca.pem"),
        "connect_certificate": str(certs / "learner.pem"),
        "connect_private_key": str(certs / "learner.key"),
        "enable_mtls": True,
    }
    link = {"tls": tls}
    cfg.write_text(
        json.dumps(
            {
                "mode": "client",
                "connect": {"endpoints": [f"tls/127.0.0.1:{port}"]},
                "scouting": {"multicast": {"enabled": False}},
                "transport": {"link": link},
            }
        )
    )
    learner = open_session(BusConfig(zenoh_config=str(cfg)))
    try:
        got = _received(
            session("dashboard"), "robocal/c1/r1/model", {"learner": learner}, "learner"
        )
    finally:
        learner.close()
    assert got == ["learner"]
    with pytest.raises(ConfigError, match="bus.zenoh_config"):
        open_session(BusConfig(zenoh_config=str(tmp_path / "missing.json5")))


def test_payloads_name_their_encoding_across_the_router(line):
    session, _, _ = line
    got = {}
    sub = session("dashboard").declare_subscriber(
        "robocal/c1/r1/*", lambda s: got.setdefault(str(s.key_expr), str(s.encoding))
    )
    time.sleep(SETTLE_S)
    publisher(session("tracker"), "robocal/c1/r1/tracker").put(b"{}")
    publisher(session("learner"), "robocal/c1/r1/model").put(b"\0")
    deadline = time.monotonic() + 10
    while len(got) < 2 and time.monotonic() < deadline:
        time.sleep(0.02)
    sub.undeclare()
    assert got == {
        "robocal/c1/r1/tracker": "application/json",
        "robocal/c1/r1/model": "application/octet-stream",
    }
