"""`vr-teleop cert`: a self-signed certificate that names the machine, with which `serve` speaks https:// and wss://
on one port (what a headset on the LAN needs for WebXR and the microphone)."""

from __future__ import annotations

import ipaddress
import json
import socket
import ssl
import urllib.error
import urllib.request

from cryptography import x509
from websockets.sync.client import connect

from vr_teleop_server.cli import main


def test_cert_names_the_machine_and_serve_speaks_https_and_wss(servers, tmp_path, capsys):
    assert main(["cert", "--out", str(tmp_path), "--name", "qt-classroom.example", "--ip", "10.1.2.3"]) == 0
    printed = capsys.readouterr().out
    certfile, keyfile = tmp_path / "vr-teleop.crt", tmp_path / "vr-teleop.key"
    assert f"--certfile {certfile} --keyfile {keyfile}" in printed and "/operator" in printed
    assert keyfile.stat().st_mode & 0o077 == 0  # the key is its owner's alone
    cert = x509.load_pem_x509_certificate(certfile.read_bytes())
    san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    names = san.get_values_for_type(x509.DNSName)
    addresses = san.get_values_for_type(x509.IPAddress)
    assert socket.gethostname() in names and "localhost" in names and "qt-classroom.example" in names
    assert ipaddress.ip_address("127.0.0.1") in addresses and ipaddress.ip_address("10.1.2.3") in addresses

    # Written again only when asked.
    assert main(["cert", "--out", str(tmp_path)]) == 1
    assert "--force" in capsys.readouterr().err

    server = servers(certfile=certfile, keyfile=keyfile)
    try:
        trust = ssl.create_default_context(cafile=str(certfile))  # the headset's "accept this certificate"
        with urllib.request.urlopen(f"https://127.0.0.1:{server.port}/operator", context=trust) as r:
            assert r.status == 200 and b"Enter VR" in r.read()
        with urllib.request.urlopen(f"https://localhost:{server.port}/vendor/three/three.module.js",
                                    context=trust) as r:
            assert "javascript" in r.headers["Content-Type"]
        # TLS and the WebSocket handshake within the 30 s failure bound (websockets' default 10 s failed a loaded run)
        with connect(f"wss://127.0.0.1:{server.port}/", ssl=trust, open_timeout=30) as ws:
            ws.send(json.dumps({"op": "call_service", "id": "t", "service": "/rosapi/get_time", "args": {}}))
            reply = json.loads(ws.recv(timeout=10))
            assert reply["op"] == "service_response" and reply["result"] is True
    finally:
        server.stop()


def test_cert_with_a_local_authority_is_trusted_by_whoever_trusts_the_authority(servers, tmp_path, capsys):
    """`--ca DIR`: the authority is made once, then reused; a client trusting only the authority accepts the
    server's certificate (what a `turns:` relay needs: browsers accept no self-signed one there)."""
    ca_dir, out, again = tmp_path / "ca", tmp_path / "server", tmp_path / "relay"
    assert main(["cert", "--out", str(out), "--ca", str(ca_dir)]) == 0
    assert "install it on the clients" in capsys.readouterr().out
    authority = ca_dir / "vr-teleop-ca.crt"
    assert (ca_dir / "vr-teleop-ca.key").stat().st_mode & 0o077 == 0
    assert main(["cert", "--out", str(again), "--ca", str(ca_dir), "--ip", "10.1.2.3"]) == 0
    assert "install it on the clients" not in capsys.readouterr().out  # the same authority, not a new one
    ca = x509.load_pem_x509_certificate(authority.read_bytes())
    for directory in (out, again):
        cert = x509.load_pem_x509_certificate((directory / "vr-teleop.crt").read_bytes())
        assert cert.issuer == ca.subject and cert.issuer != cert.subject
        cert.verify_directly_issued_by(ca)
    assert ca.extensions.get_extension_for_class(x509.BasicConstraints).value.ca

    server = servers(certfile=out / "vr-teleop.crt", keyfile=out / "vr-teleop.key")
    try:
        trust = ssl.create_default_context(cafile=str(authority))  # the authority only, not the server's own
        with urllib.request.urlopen(f"https://127.0.0.1:{server.port}/operator", context=trust) as r:
            assert r.status == 200
        untrusting = ssl.create_default_context(cafile=str(out / "vr-teleop.crt"))
        try:
            urllib.request.urlopen(f"https://127.0.0.1:{server.port}/operator", context=untrusting)
            raise AssertionError("a certificate signed by an authority is not self-signed: trusting it alone fails")
        except urllib.error.URLError as exc:
            assert "certificate verify failed" in str(exc)
    finally:
        server.stop()
