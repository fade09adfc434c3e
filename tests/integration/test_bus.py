"""The message layer over a real Zenoh session, across separate processes (no mocks).

The node under test is `cinetransfer relay`, the smallest complete node: it decodes,
validates, re-encodes and republishes, and reports Health like every service.
"""
import json
import subprocess
import sys
import threading

import msgpack
import pytest
import zenoh

from cinetransfer.shared import codec, zenoh_config
from cinetransfer.shared import messages as M
from conftest import connect_flags, cpu_seconds, spawn, stop, wait_for
from contract.test_codec import assert_same, sample_messages


class Listener:
    """The test's own real session: collects samples per key and liveliness changes."""

    def __init__(self, opts):
        self.session = zenoh_config.open_session(opts)
        self.samples: dict[str, list[bytes]] = {}
        self.alive: set[str] = set()
        self.lock = threading.Lock()
        self._decl = [self.session.declare_subscriber("ct/**", self._on),
                      self.session.liveliness().declare_subscriber("ct/*/alive/*", self._on_alive, history=True)]

    def _on(self, s):
        with self.lock:
            self.samples.setdefault(str(s.key_expr), []).append(s.payload.to_bytes())

    def _on_alive(self, s):
        import zenoh
        with self.lock:
            (self.alive.add if s.kind == zenoh.SampleKind.PUT else self.alive.discard)(str(s.key_expr).split("/")[-1])

    def got(self, key):
        with self.lock:
            return list(self.samples.get(key, []))

    def relayed(self):
        """What the relay put out, decoded, without the fixture's route probes."""
        return [m for m in map(codec.decode, self.got("ct/t/out")) if not _is_probe(m)]

    def last_health(self, node, rig="t"):
        h = self.got(f"ct/{rig}/health/{node}")
        return codec.decode(h[-1]) if h else None

    def close(self):
        for d in self._decl:
            d.undeclare()
        self.session.close()


@pytest.fixture
def listener(listener_opts):
    lst = Listener(listener_opts)
    yield lst
    lst.close()


PROBE_NODE = "route-probe"
#: the test's own messages must all arrive: Zenoh's default for a put is to drop it when the link
#: is congested (several large frames at once on a loaded machine)
BLOCK = zenoh.CongestionControl.BLOCK


def _is_probe(msg) -> bool:
    return isinstance(msg, M.Health) and msg.node == PROBE_NODE


@pytest.fixture
def relay(port, listener, tmp_path):
    proc = spawn("relay", "--rig", "t", "--from", "ct/t/in", "--to", "ct/t/out", "--health-period", "0.2",
                 "--no-drop", *connect_flags(port), log=tmp_path / "relay.log")
    wait_for(lambda: "relay" in listener.alive or proc.poll() is not None, what="relay liveliness",
             progress=lambda: cpu_seconds(proc))
    assert proc.poll() is None, (tmp_path / "relay.log").read_text()
    # Liveliness does not mean the relay's subscription has reached this publisher yet: on a loaded
    # machine the first messages were lost. Probe until one comes through (tests leave probes out).
    pub = listener.session.declare_publisher("ct/t/in", congestion_control=BLOCK)
    probe = codec.encode(M.Health(node=PROBE_NODE))
    wait_for(lambda: pub.put(probe) or listener.got("ct/t/out"), what="the relay's route")
    pub.undeclare()
    yield proc
    rc = stop(proc)
    assert rc == 0, (tmp_path / "relay.log").read_text()


def test_every_message_type_round_trips_across_processes(listener, relay):
    pub = listener.session.declare_publisher("ct/t/in", congestion_control=BLOCK)
    sent = list(sample_messages())
    for msg in sent:
        pub.put(codec.encode(msg))
    wait_for(lambda: len(listener.relayed()) >= len(sent), what="relayed messages")
    received = listener.relayed()
    first = received[0].seq  # after the route probes
    for i, (a, b) in enumerate(zip(sent, received, strict=True)):
        assert_same(a, b, ignore=("seq",))  # the relay is a new stream: it numbers its own output
        assert b.seq == first + i
    pub.undeclare()


def test_malformed_and_wrong_version_are_rejected_and_counted(listener, relay):
    pub = listener.session.declare_publisher("ct/t/in", congestion_control=BLOCK)
    good = codec.encode(M.Command(action="start"))
    _, header, _ = codec._split(good)
    header["v"] = 7
    h = msgpack.packb(header, use_bin_type=True)
    wrong_version = codec._PREFIX.pack(codec.MAGIC, codec.FORMAT, len(h)) + h
    pub.put(b"\x00garbage that is not a message")
    pub.put(wrong_version)
    pub.put(good)
    # The node keeps running: the valid message after the bad ones still comes through.
    wait_for(listener.relayed, what="valid message after bad ones")
    assert [m.action for m in listener.relayed()] == ["start"]
    health = wait_for(lambda: (h := listener.last_health("relay")) and h.rejected >= 2 and h.published >= 2 and h,
                      what="health")  # published: at least one route probe and the command
    assert health.rejected == 2 and health.received == health.published + 2
    assert "version 7 is not supported" in health.last_error
    assert relay.poll() is None
    pub.undeclare()


def test_sigterm_exits_cleanly_and_liveliness_goes(port, listener, tmp_path):
    proc = spawn("relay", "--rig", "t", "--name", "r2", "--from", "ct/t/x", "--to", "ct/t/y", *connect_flags(port),
                 log=tmp_path / "r2.log")
    wait_for(lambda: "r2" in listener.alive, what="r2 alive", progress=lambda: cpu_seconds(proc))
    proc.terminate()
    assert proc.wait(60) == 0, (tmp_path / "r2.log").read_text()  # a hang ceiling: exit is slow under load
    wait_for(lambda: "r2" not in listener.alive, what="liveliness token dropped")


def test_config_error_names_the_field(tmp_path):
    r = subprocess.run([sys.executable, "-m", "cinetransfer", "relay", "--from", "a", "--to", "b",
                        "--connect", "nonsense"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "endpoint 'nonsense'" in r.stderr


def test_monitor_once_and_json(port, listener, relay):
    pub = listener.session.declare_publisher("ct/t/in", congestion_control=BLOCK)
    done = threading.Event()

    def feed():
        while not done.is_set():
            pub.put(codec.encode(M.Command(action="start")))
            done.wait(0.05)

    t = threading.Thread(target=feed)
    t.start()
    try:
        r = subprocess.run([sys.executable, "-m", "cinetransfer", "monitor", "--once", "--duration", "1.5",
                            *connect_flags(port)], capture_output=True, text=True, timeout=60)
        assert r.returncode == 0, r.stderr
        assert "ct/t/out" in r.stdout and "Command start" in r.stdout
        assert "t/relay" in r.stdout.split("alive:")[1]
        r = subprocess.run([sys.executable, "-m", "cinetransfer", "monitor", "ct/t/out", "--json", "--once",
                            "--duration", "1.0", *connect_flags(port)], capture_output=True, text=True, timeout=60)
        lines = [json.loads(x) for x in r.stdout.splitlines()]
        assert lines and all(x["key"] == "ct/t/out" and x["msg"]["action"] == "start" for x in lines)
    finally:
        done.set()
        t.join()
        pub.undeclare()


def test_monitor_joins_the_local_router_by_default(tmp_path):
    """`cinetransfer monitor` with no flags sees a `deploy up local` deployment (router on 7447)."""
    import socket

    with socket.socket() as s:
        if s.connect_ex(("127.0.0.1", 7447)) == 0:
            pytest.skip("something already listens on 127.0.0.1:7447 (a running deployment?)")
    router = spawn("router", log=tmp_path / "router.log")  # default: tcp/127.0.0.1:7447
    try:
        opts = zenoh_config.ZenohOptions(mode="client", connect=("tcp/127.0.0.1:7447",))
        session = wait_for(lambda: _try_open(opts), what="router up", progress=lambda: cpu_seconds(router))
        pub = session.declare_publisher("ct/dflt/vehicle/state")
        done = threading.Event()

        def feed():
            while not done.is_set():
                pub.put(codec.encode(M.VehicleState(backend="sim")))
                done.wait(0.05)

        t = threading.Thread(target=feed)
        t.start()
        try:
            r = subprocess.run([sys.executable, "-m", "cinetransfer", "monitor", "--once", "--duration", "2"],
                               capture_output=True, text=True, timeout=60)
        finally:
            done.set()
            t.join()
            pub.undeclare()
            session.close()
        assert r.returncode == 0, r.stderr
        assert "ct/dflt/vehicle/state" in r.stdout and "VehicleState sim" in r.stdout
    finally:
        assert stop(router) == 0


def _try_open(opts):
    try:
        return zenoh_config.open_session(opts)
    except Exception:  # the router is not listening yet
        return None
