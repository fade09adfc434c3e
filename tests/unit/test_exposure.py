"""The exposure rule on the effective Zenoh configuration (shared/exposure.py), case by case."""
import json

import pytest

from cinetransfer.shared import exposure
from cinetransfer.shared.errors import ConfigError
from cinetransfer.shared.exposure import Exposure
from cinetransfer.shared.zenoh_config import ZenohOptions, build_config


def ex(mode="client", listen=(), connect=(), mtls=False, multicast=False) -> Exposure:
    return Exposure(mode, tuple(listen), tuple(connect), mtls, multicast)


@pytest.mark.parametrize("e", [
    ex("router", listen=["tcp/127.0.0.1:7447", "tcp/[::1]:7447", "tcp/localhost:1", "unixsock-stream//tmp/s"]),
    ex("router", listen=["tls/0.0.0.0:7448"], mtls=True),
    ex("router", listen=["tcp/127.0.0.1:7447"], connect=["tls/192.0.2.10:7448"], mtls=True),
    ex("client", connect=["tcp/192.0.2.10:7447"]),
    ex("peer", listen=["tcp/127.0.0.1:0"], connect=["tcp/127.0.0.2:7447"]),
])
def test_allowed(e):
    exposure.check(e)


@pytest.mark.parametrize("e, says", [
    (ex("router", listen=["tcp/0.0.0.0:7447"]), "unauthenticated"),
    (ex("router", listen=["udp/[::]:7447"]), "unauthenticated"),
    (ex("router", listen=["tcp/drone.local:7447"]), "unauthenticated"),  # a name may resolve anywhere
    (ex("router", listen=["tls/127.0.0.1:7448"]), "client certificates"),
    (ex("router", listen=["quic/0.0.0.0:7448"]), "client certificates"),
    (ex("peer", listen=["tls/0.0.0.0:7448"], mtls=True), "peer mode off loopback"),
    (ex("peer", connect=["tcp/192.0.2.10:7447"]), "peer mode off loopback"),
    (ex("peer", listen=["tcp/127.0.0.1:0"], multicast=True), "multicast"),
])
def test_refused_with_one_line(e, says):
    with pytest.raises(ConfigError, match=says) as err:
        exposure.check(e)
    assert "\n" not in str(err.value)


def test_a_config_file_counts_and_zenoh_defaults_are_made_explicit(tmp_path):
    f = tmp_path / "z.json5"
    # a file without endpoints: a peer stays on loopback (Zenoh's own default is every interface)
    f.write_text(json.dumps({"mode": "peer"}))
    assert exposure.of_config(build_config(ZenohOptions(config_file=str(f)))).listen == ("tcp/127.0.0.1:0",)
    # a router given no listener anywhere would take Zenoh's default tcp/[::]:7447: refused
    with pytest.raises(ConfigError, match=r"tcp/\[::\]:7447"):
        ZenohOptions(mode="router", config_file=str(f)).validate()
    # the file's listeners are checked like flags
    f.write_text(json.dumps({"listen": {"endpoints": ["tcp/0.0.0.0:7447"]}}))
    with pytest.raises(ConfigError, match="unauthenticated"):
        ZenohOptions(mode="router", config_file=str(f)).validate()
    # so are raw settings
    with pytest.raises(ConfigError, match="unauthenticated"):
        ZenohOptions(mode="router", extra=(("listen/endpoints", '["tcp/0.0.0.0:7447"]'),)).validate()
    # and a file that is not valid JSON5 is one line too
    f.write_text("{mode: ")
    with pytest.raises(ConfigError, match="zenoh configuration file") as err:
        ZenohOptions(config_file=str(f)).validate()
    assert "\n" not in str(err.value)
