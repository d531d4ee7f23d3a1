"""TURN credentials and the ICE servers service (issue 30), without a network: the credentials are coturn's
use-auth-secret form (checked against OpenSSL's HMAC), `serve` refuses bad TURN flags by name, and
/vr_teleop/media/ice_servers hands an operator fresh credentials under the offer's access rules while neither the
recording nor the log keeps them. The relay itself (coturn accepting and refusing them) is tests/test_nat_turn.py."""

from __future__ import annotations

import base64
import logging
import subprocess
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

from client_protocol import names
from testbed.media_client import Rosbridge
from vr_teleop_server.cli import main as cli_main
from vr_teleop_server.media.turn import IceConfig, check_url, credentials

SECRET = "s3cret-shared-with-coturn"
TURN = ("turns:relay.example:443?transport=tcp", "turn:relay.example:3478?transport=udp")


def test_credentials_are_coturns_time_limited_form() -> None:
    username, password, expires = credentials(SECRET, "op-1234", 600, now=1_700_000_000.4)
    assert username == "1700000600:op-1234" and expires == 1_700_000_600
    # the relay's side of the check, computed by OpenSSL: base64(HMAC-SHA1(secret, username))
    mac = subprocess.run(["openssl", "dgst", "-sha1", "-hmac", SECRET, "-binary"], input=username.encode(),
                         capture_output=True, check=True).stdout
    assert password == base64.b64encode(mac).decode()
    assert credentials("another secret", "op-1234", 600, now=1_700_000_000)[1] != password


def test_ice_config_gives_stun_as_is_and_turn_with_credentials() -> None:
    config = IceConfig(urls=("stun:stun.example:3478", *TURN), secret=SECRET, ttl_s=60)
    servers, expires = config.servers("op-1", now=1000.0)
    assert servers[0] == {"urls": ["stun:stun.example:3478"], "username": "", "credential": ""}
    assert servers[1]["urls"] == list(TURN) and servers[1]["username"] == "1060:op-1" and expires == 1060
    assert SECRET not in repr(config)
    rtc = config.rtc()  # the server's own peer: the same URLs, its own credentials
    assert [s.urls for s in rtc] == [["stun:stun.example:3478"], list(TURN)]
    assert rtc[1].username.endswith(":vr_teleop_server") and rtc[1].credential
    assert IceConfig().servers("op-1") == ([], 0.0)


@pytest.mark.parametrize("url, says", [("http://relay:3478", "not an ICE server URL"),
                                       ("turns:relay:443?transport=udp", "runs over TCP"),
                                       ("turn:relay:99999", "1..65535")])
def test_bad_urls_are_refused_by_name(url: str, says: str) -> None:
    with pytest.raises(ValueError, match=says):
        check_url(url)


def test_serve_refuses_turn_without_a_secret_and_bad_urls(capsys: pytest.CaptureFixture[str],
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("VR_TELEOP_TURN_SECRET", raising=False)
    assert cli_main(["serve", "--port", "0", "--turn-url", TURN[0]]) == 2
    assert "--turn-secret" in capsys.readouterr().err
    assert cli_main(["serve", "--port", "0", "--turn-url", "turn:", "--turn-secret", SECRET]) == 2
    err = capsys.readouterr().err
    assert "not an ICE server URL" in err and SECRET not in err


async def test_the_service_gives_fresh_credentials_under_the_offers_rules(servers, tmp_path: Path,
                                                                          caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.DEBUG)
    record = tmp_path / "session.mcap"
    server = servers(operator_token="op-token", spectator_token="spec-token", turn_urls=TURN, turn_secret=SECRET,
                     turn_ttl=120, record=record)
    seen: list[str] = []
    try:
        stranger = await Rosbridge.open(server.url)  # no token: no camera, no media, no credentials
        reply = await stranger.call(names.MEDIA_ICE_SERVERS_SERVICE, {})
        assert reply["op"] == "status" and "authenticate" in reply["msg"]
        await stranger.close()
        operator = await Rosbridge.open(server.url, token="op-token")
        before = time.time()
        values = (await operator.call(names.MEDIA_ICE_SERVERS_SERVICE, {}))["values"]
        assert values["success"] and len(values["ice_servers"]) == 1
        turn = values["ice_servers"][0]
        assert turn["urls"] == list(TURN)
        expiry, key = turn["username"].split(":", 1)
        assert key.startswith("op-") and before + 120 - 1 <= int(expiry) <= time.time() + 120
        assert values["expires"] == int(expiry)
        assert turn["credential"] == credentials(SECRET, key, 0, int(expiry))[1]
        seen.append(turn["credential"])
        # a spectator watches: it may have media, so it gets credentials of its own
        spectator = await Rosbridge.open(server.url, token="spec-token")
        values = (await spectator.call(names.MEDIA_ICE_SERVERS_SERVICE, {}))["values"]
        assert values["success"] and values["ice_servers"][0]["username"].split(":", 1)[1] != key
        seen.append(values["ice_servers"][0]["credential"])
        await spectator.close()
        await operator.close()
    finally:
        server.stop()
    with record.open("rb") as f:
        data = b"\n".join(message.data for _schema, _channel, message in make_reader(f).iter_messages())
    assert names.MEDIA_ICE_SERVERS_SERVICE.encode() in data  # the call is recorded, its answer is not
    for secret in (SECRET, *seen):
        assert secret.encode() not in data, "a TURN credential reached the recording"
        assert secret not in caplog.text, "a TURN credential reached the log"


async def test_without_turn_the_list_is_empty_and_says_why(servers) -> None:
    server = servers()
    try:
        ros = await Rosbridge.open(server.url)
        values = (await ros.call(names.MEDIA_ICE_SERVERS_SERVICE, {}))["values"]
        assert values["success"] and values["ice_servers"] == [] and values["expires"] == 0
        assert "no ICE servers configured" in values["message"]
        await ros.close()
    finally:
        server.stop()
