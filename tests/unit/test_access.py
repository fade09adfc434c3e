"""The access rules cover every topic, and insecure listeners are refused before anything starts."""
import pytest

from cinetransfer.deploy.config import ConfigError, load_config
from cinetransfer.deploy.rundir import resolve_run_dir
from cinetransfer.shared import access, keys
from cinetransfer.shared.zenoh_config import ZenohOptions


def test_every_topic_has_its_publishers():
    assert set(access.PUBLISHERS) == set(keys.TOPICS)
    assert access.PUBLISHERS[keys.SETPOINT] == ("planner",)
    for cmd in (keys.BRIDGE_COMMAND, keys.PLANNER_COMMAND):
        assert access.PUBLISHERS[cmd] == (access.OPERATOR,)
    assert access.CONFIG_READERS == (access.OPERATOR,)


@pytest.mark.parametrize("identity, may, may_not", [
    ("planner", "ct/*/planner/setpoint", "ct/*/vehicle/command"),
    ("operator", "ct/*/vehicle/command", "ct/*/planner/setpoint"),
    ("detector", "ct/*/detector/measurement", "ct/*/planner/setpoint"),
    ("observer", "ct/*/health/observer", "ct/*/planner/command"),
])
def test_rights(identity, may, may_not):
    put = access.rights(identity)["put"]
    assert may in put and may_not not in put


def test_acl_denies_by_default_and_links_carry_only_their_side():
    acl = access.access_control()
    assert acl["enabled"] and acl["default_permission"] == "deny"
    rules = {r["id"]: r for r in acl["rules"]}
    ground_put = rules["cert-ground:put"]["key_exprs"]
    assert "ct/*/vehicle/command" in ground_put and "ct/*/planner/setpoint" not in ground_put
    assert "ct/*/planner/setpoint" in rules["cert-onboard:put"]["key_exprs"]


def test_a_user_name_counts_only_on_local_links_and_a_certificate_only_on_tls():
    """Subjects never overlap on one link, so rights are never the union of user and certificate."""
    subjects = access.access_control()["subjects"]
    for s in subjects:
        if s.get("usernames"):
            assert s["link_protocols"] == ["tcp", "unixsock-stream"] and "cert_common_names" not in s, s
        else:
            assert s["cert_common_names"] and s["link_protocols"] == ["tls", "quic"] and "usernames" not in s, s
    assert {"id": "cert-ground", "cert_common_names": ["ground"], "link_protocols": ["tls", "quic"]} in subjects


@pytest.mark.parametrize("ep", ["tcp/0.0.0.0:7448", "tcp/192.0.2.10:7448", "udp/[::]:7448"])
def test_plain_listener_off_loopback_is_refused(ep):
    with pytest.raises(ValueError, match="unauthenticated"):
        ZenohOptions(mode="router", listen=(ep,)).validate()


def test_tls_listener_without_client_certificates_is_refused():
    with pytest.raises(ValueError, match="client certificates"):
        ZenohOptions(mode="router", listen=("tls/0.0.0.0:7448",)).validate()
    ZenohOptions(mode="router", listen=("tls/0.0.0.0:7448", "tcp/127.0.0.1:7449"), tls_mtls=True).validate()


def test_shipped_split_configs_cross_the_radio_over_tls_only(monkeypatch):
    monkeypatch.setenv("CT_ONBOARD_LISTEN", "0.0.0.0")
    monkeypatch.setenv("CT_DRONE_ADDR", "192.0.2.10")
    onboard, ground = load_config("onboard").routers[0], load_config("ground").routers[0]
    assert "tls/0.0.0.0:7448" in onboard.argv and onboard.identity == "onboard"
    assert "tls/192.0.2.10:7448" in ground.argv and ground.identity == "ground"
    for r in (onboard, ground):
        listens = [r.argv[i + 1] for i, a in enumerate(r.argv) if a == "--listen"]
        assert all(ep.startswith("tls/") or "127.0.0.1" in ep for ep in listens)


def test_a_config_with_a_plain_public_listener_is_refused(tmp_path):
    cfg = tmp_path / "open.yaml"
    cfg.write_text("routers:\n  - name: router\n    zenoh:\n      listen: [tcp/0.0.0.0:7447]\n")
    with pytest.raises(ConfigError, match="unauthenticated connections"):
        load_config(str(cfg))


def test_run_dir_is_absolute_and_independent_of_the_working_directory(tmp_path, monkeypatch):
    monkeypatch.setenv("CT_STATE_DIR", str(tmp_path / "state"))
    monkeypatch.chdir(tmp_path)
    a = resolve_run_dir(load_config("local"))
    monkeypatch.chdir("/")
    assert resolve_run_dir(load_config("local")) == a == tmp_path / "state" / "deploy" / "local"
    one, two = tmp_path / "x" / "t.yaml", tmp_path / "y" / "t.yaml"
    for f in (one, two):
        f.parent.mkdir()
        f.write_text("nodes:\n  - {name: n, command: relay}\n")
    assert resolve_run_dir(load_config(str(one))) != resolve_run_dir(load_config(str(two)))
    monkeypatch.chdir(tmp_path)
    assert resolve_run_dir(load_config(str(one)), "rel") == tmp_path / "rel"
