"""The bus only obeys who it should: real routers with the shipped configs' rules, real TLS.

Every "not delivered" check is bracketed by positive controls on the same subscriber: first an
authorised message proves the subscription reached the router, then after the attack the
attacker's own allowed message (its health key, on the same link, so routed after the attack)
proves the router has already processed the attack, then an authorised message still arrives.
"""
import json
import threading
from pathlib import Path

import pytest
import zenoh

from cinetransfer.deploy import certs
from cinetransfer.deploy.config import load_config
from cinetransfer.deploy.security import prepare_security, security_flags
from cinetransfer.shared import access, keys
from cinetransfer.shared.zenoh_config import ZenohOptions, free_tcp_port, open_session
from conftest import cpu_seconds, spawn, stop, wait_for

RIG = "rig0"


class Inbox:
    """Everything a session receives under ct/<rig>/**, by key."""

    def __init__(self, session: zenoh.Session) -> None:
        self.lock = threading.Lock()
        self.got: list[tuple[str, bytes]] = []
        self.sub = session.declare_subscriber(f"ct/{RIG}/**", self._on)

    def _on(self, s: zenoh.Sample) -> None:
        with self.lock:
            self.got.append((str(s.key_expr), s.payload.to_bytes()))

    def has(self, key: str, payload: bytes) -> bool:
        with self.lock:
            return (key, payload) in self.got

    def payloads(self) -> list[bytes]:
        with self.lock:
            return [p for _, p in self.got]


def client(endpoint: str, identity: str | None, secrets: Path | None, **kw) -> ZenohOptions:
    return ZenohOptions(mode="client", connect=(endpoint,), identity=identity,
                        secrets=str(secrets) if secrets else None, **kw)


def _try_open(opts: ZenohOptions):
    try:
        return open_session(opts)
    except Exception:  # router not listening yet
        return None


def start_router(cfg, run_dir: Path, tmp_path: Path, name: str):
    r = cfg.routers[0]
    return spawn(*r.argv, *security_flags(cfg, run_dir, r), log=tmp_path / f"{name}.log")


@pytest.fixture
def local_router(tmp_path, port, monkeypatch):
    """The shipped local config's router, its rules and generated credentials."""
    monkeypatch.setenv("CT_ROUTER_PORT", str(port))
    monkeypatch.delenv("CT_SECRETS", raising=False)
    cfg = load_config("local")
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    prepare_security(cfg, run_dir)
    proc = start_router(cfg, run_dir, tmp_path, "router")
    ep = f"tcp/127.0.0.1:{port}"
    sec = run_dir / "secrets"
    wait_for(lambda: _try_open(client(ep, "observer", sec)), what="router up",
             progress=lambda: cpu_seconds(proc)).close()
    yield ep, sec
    assert stop(proc) == 0


def attack_then_barrier(ep: str, sec: Path, who: str, inbox: Inbox, attacks: list[tuple[str, bytes]]) -> None:
    """`who` sends `attacks`, then its own health message; wait until the barrier is delivered."""
    with open_session(client(ep, who, sec)) as s:
        for key, payload in attacks:
            s.put(key, payload)
        barrier = (keys.health(RIG, who), f"barrier-{who}".encode())
        s.put(*barrier)
        wait_for(lambda: inbox.has(*barrier), timeout=30, what=f"{who}'s barrier")


def test_only_the_planner_sets_points_and_only_the_operator_commands(local_router):
    ep, sec = local_router
    sp, vcmd, pcmd = keys.SETPOINT.key(RIG), keys.BRIDGE_COMMAND.key(RIG), keys.PLANNER_COMMAND.key(RIG)
    with open_session(client(ep, "autopilot_bridge", sec)) as bridge_s:
        bridge = Inbox(bridge_s)
        with open_session(client(ep, "planner", sec)) as planner, open_session(client(ep, "operator", sec)) as op:
            # given: the bridge's subscription is in place (an authorised setpoint and command arrive)
            planner.put(sp, b"good-setpoint-0")
            op.put(vcmd, b"good-command-0")
            wait_for(lambda: bridge.has(sp, b"good-setpoint-0") and bridge.has(vcmd, b"good-command-0"),
                     timeout=30, what="authorised messages")
            # when: authenticated but unauthorised identities publish setpoints and commands
            for who in ("detector", "smoother", "observer", "camera", "autopilot_bridge"):
                attack_then_barrier(ep, sec, who, bridge, [(sp, f"bad-setpoint-{who}".encode()),
                                                           (vcmd, f"bad-command-{who}".encode()),
                                                           (pcmd, f"bad-plan-{who}".encode())])
            # then: none of them was delivered, and authorised traffic still is
            planner.put(sp, b"good-setpoint-1")
            op.put(vcmd, b"good-command-1")
            op.put(pcmd, b"good-plan-1")
            wait_for(lambda: bridge.has(sp, b"good-setpoint-1") and bridge.has(vcmd, b"good-command-1")
                     and bridge.has(pcmd, b"good-plan-1"), timeout=30, what="authorised messages after the attack")
            bad = [p for p in bridge.payloads() if p.startswith(b"bad-")]
            assert bad == []


def test_a_client_without_valid_credentials_cannot_join(local_router):
    ep, sec = local_router
    with pytest.raises(zenoh.ZError):
        open_session(client(ep, None, None))  # no user/password at all
    wrong = sec.parent / "wrong"
    wrong.mkdir()
    (wrong / "users.txt").write_text("planner:not-the-password\n")
    with pytest.raises(zenoh.ZError):
        open_session(client(ep, "planner", wrong))
    open_session(client(ep, "planner", sec)).close()  # the right password does join


def test_config_queries_are_answered_only_to_the_operator(local_router):
    ep, sec = local_router
    key = keys.config(RIG, "planner")
    with open_session(client(ep, "planner", sec)) as planner:
        q = planner.declare_queryable(key, lambda query: query.reply(key, b"max_speed_m_s=12"))

        def ask(who: str) -> list[bytes]:
            with open_session(client(ep, who, sec)) as s:
                return [r.ok.payload.to_bytes() for r in s.get(key, timeout=10.0) if r.ok is not None]

        # the operator gets the answer (also proves the queryable is declared at the router)
        wait_for(lambda: ask("operator") == [b"max_speed_m_s=12"], timeout=60, what="operator's config reply")
        for who in ("observer", "detector", "autopilot_bridge"):
            assert ask(who) == [], who
        assert ask("operator") == [b"max_speed_m_s=12"]
        q.undeclare()


@pytest.fixture
def split(tmp_path, monkeypatch):
    """The shipped onboard and ground routers on one host, linked over mutual TLS, each with only
    its own host's folder from `deploy certs` (yields that parent folder and the endpoints)."""
    sec = tmp_path / "secrets"
    certs.generate_split(sec)
    p_onboard, p_link, p_ground = free_tcp_port(), free_tcp_port(), free_tcp_port()
    monkeypatch.setenv("CT_ONBOARD_PORT", str(p_link))
    procs = []
    try:
        for name, port in (("onboard", p_onboard), ("ground", p_ground)):
            monkeypatch.setenv("CT_ROUTER_PORT", str(port))
            monkeypatch.setenv("CT_SECRETS", str(sec / name))
            cfg = load_config(name)
            run_dir = tmp_path / name
            run_dir.mkdir()
            prepare_security(cfg, run_dir)
            procs.append(start_router(cfg, run_dir, tmp_path, name))
            wait_for(lambda: _try_open(client(f"tcp/127.0.0.1:{port}", "observer", sec / name)),
                     what=f"{name} up").close()
        yield sec, f"tcp/127.0.0.1:{p_onboard}", f"tls/127.0.0.1:{p_link}", f"tcp/127.0.0.1:{p_ground}"
    finally:
        for p in reversed(procs):
            assert stop(p) == 0


def _login(user: str, password: str) -> tuple[tuple[str, str], ...]:
    return (("transport/auth/usrpwd/user", json.dumps(user)), ("transport/auth/usrpwd/password", json.dumps(password)))


def send_until_seen(session: zenoh.Session, inbox: Inbox, key: str, payload: bytes) -> None:
    """Publish until `inbox` has it (the first may go out before the subscription reached the router)."""
    def sent() -> bool:
        session.put(key, payload)
        return inbox.has(key, payload)

    wait_for(sent, timeout=60, interval=0.2, what=f"{payload!r} on {key}")


def test_each_host_holds_only_its_own_passwords(split):
    """The ground folder's passwords open the ground router, not the drone's: a stolen ground
    station cannot join the onboard router as any local identity."""
    sec, onboard, _, ground = split
    open_session(client(ground, "operator", sec / "ground")).close()
    with pytest.raises(zenoh.ZError):
        open_session(client(onboard, "operator", sec / "ground"))
    with pytest.raises(ValueError, match="no password for identity 'planner'"):
        open_session(client(onboard, "planner", sec / "ground"))
    open_session(client(onboard, "operator", sec / "onboard")).close()


def test_tls_listener_refuses_clients_without_a_certificate_of_the_ca(split, tmp_path):
    sec, _, link, _ = split
    gsec = sec / "ground"
    # with the deployment's certificate: joins
    open_session(client(link, "ground", gsec)).close()
    # the right user and password, and it trusts the CA, but shows no certificate: refused
    creds = _login("ground", access.read_password(gsec, "ground"))
    with pytest.raises(zenoh.ZError):
        open_session(client(link, None, None, tls_root_ca=str(gsec / "ca.pem"), extra=creds))
    # the same with a certificate of another CA: refused
    other = tmp_path / "other"
    certs.generate(other)
    with pytest.raises(zenoh.ZError):
        open_session(client(link, None, None, tls_root_ca=str(gsec / "ca.pem"), tls_cert=str(other / "ground.pem"),
                            tls_key=str(other / "ground-key.pem"), tls_mtls=True, extra=creds))
    # control: the same explicit options with the deployment's own certificate do join
    open_session(client(link, None, None, tls_root_ca=str(gsec / "ca.pem"), tls_cert=str(gsec / "ground.pem"),
                        tls_key=str(gsec / "ground-key.pem"), tls_mtls=True, extra=creds)).close()


def test_across_the_link_the_ground_may_command_but_not_set_points(split):
    sec, onboard, link, ground = split
    sp, vcmd = keys.SETPOINT.key(RIG), keys.BRIDGE_COMMAND.key(RIG)
    with open_session(client(onboard, "autopilot_bridge", sec / "onboard")) as bridge_s, \
            open_session(client(ground, "operator", sec / "ground")) as op:
        bridge = Inbox(bridge_s)
        # given: the link is up and the bridge's subscription reached the ground router
        n = iter(range(10**6))

        def prime() -> bool:
            op.put(vcmd, f"prime-{next(n)}".encode())
            return any(p.startswith(b"prime-") for p in bridge.payloads())

        wait_for(prime, timeout=60, interval=0.2, what="operator command across the link")
        # when: a ground node (authenticated on the ground router) tries to set points
        attack_then_barrier(ground, sec / "ground", "detector", bridge, [(sp, b"bad-setpoint-detector")])
        # when: a client holding the ground router's own certificate and password joins the onboard
        # router's TLS listener directly: it is the ground link, which may command but not set points
        with open_session(client(link, "ground", sec / "ground")) as fake_ground:
            fake_ground.put(sp, b"bad-setpoint-link")
            fake_ground.put(vcmd, b"link-command")
            wait_for(lambda: bridge.has(vcmd, b"link-command"), timeout=30, what="command from the link")
        # then: an operator command still crosses, no setpoint did
        op.put(vcmd, b"good-command-1")
        wait_for(lambda: bridge.has(vcmd, b"good-command-1"), timeout=30, what="operator command")
        assert [p for p in bridge.payloads() if p.startswith(b"bad-")] == []


@pytest.mark.parametrize("user, key, payload", [
    ("planner", keys.SETPOINT, b"bad-setpoint-as-planner"),
    ("autopilot_bridge", keys.VEHICLE_STATE, b"bad-state-as-bridge"),
])
def test_over_tls_the_certificate_not_the_user_name_decides(split, user, key, payload):
    """The ground certificate logging in as an onboard identity (with that identity's real
    password, the worst case) gets the ground link's rights: no setpoint, no vehicle state."""
    sec, onboard, link, _ = split
    gsec, osec = sec / "ground", sec / "onboard"
    k, vcmd = key.key(RIG), keys.BRIDGE_COMMAND.key(RIG)
    borrowed = client(link, None, None, tls_root_ca=str(gsec / "ca.pem"), tls_cert=str(gsec / "ground.pem"),
                      tls_key=str(gsec / "ground-key.pem"), tls_mtls=True,
                      extra=_login(user, access.read_password(osec, user)))
    with open_session(client(onboard, "observer", osec)) as watch_s:
        watch = Inbox(watch_s)
        # control: the same user name and password on the router's local listener may publish it
        with open_session(client(onboard, user, osec)) as local:
            send_until_seen(local, watch, k, b"local-" + payload)
        # when: over TLS, with the ground certificate, it publishes, then a command (the ground's right)
        with open_session(borrowed) as s:
            s.put(k, payload)
            s.put(vcmd, b"barrier-" + payload)
            wait_for(lambda: watch.has(vcmd, b"barrier-" + payload), timeout=30, what="the link's command")
        # then: the command it may send arrived after the forged message would have; the forgery did not
        assert not watch.has(k, payload)
