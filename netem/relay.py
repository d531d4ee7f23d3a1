"""coturn as the emulator's TURN relay: the configuration a deployment uses (shared-secret time-limited credentials,
TURN on 3478 over UDP and TCP, TURN over TLS on 443), written to a file and run in the relay namespace.

The same settings, with a real certificate and the relay's public address, are what docs/guides/deployment.md tells a
deployment to put in /etc/turnserver.conf."""

from __future__ import annotations

from pathlib import Path

REALM = "vr-teleop"
PORT = 3478
TLS_PORT = 443


def coturn_config(ip: str, secret: str, certfile: Path, keyfile: Path, log_file: Path) -> str:
    """turnserver.conf for a relay listening and relaying on `ip`."""
    return "\n".join([
        f"listening-ip={ip}", f"relay-ip={ip}", f"listening-port={PORT}", f"tls-listening-port={TLS_PORT}",
        "use-auth-secret", f"static-auth-secret={secret}", f"realm={REALM}",
        f"cert={certfile}", f"pkey={keyfile}",
        "no-dtls",            # TLS over TCP on 443 is what a firewall lets out; DTLS is not needed
        "no-cli", "no-multicast-peers", "fingerprint",
        f"log-file={log_file}", "simple-log", "verbose",
        "min-port=49152", "max-port=65535", "",
    ])
