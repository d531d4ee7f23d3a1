"""A TLS certificate for the machine's names and addresses: self-signed, or signed by a local authority.

WebXR and the microphone exist only in a secure context, so a headset on the classroom LAN must reach the server
over https:// and wss://. A certificate that names every host name and IP address the machine answers to (as
subject alternative names: browsers ignore the common name) lets `serve --certfile --keyfile` serve both on one
port; the headset's browser is told once to accept it.

Some clients cannot be told to accept one certificate: Chromium refuses a self-signed `turns:` relay outright. For
those, `make_authority` makes a local certificate authority (what a school's IT installs once on its headsets and
browsers), and `make_certificate(..., authority=...)` signs the server's or the relay's certificate with it.
"""

from __future__ import annotations

import datetime
import ipaddress
import os
import socket
from dataclasses import dataclass
from pathlib import Path

import psutil
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

IPAddress = ipaddress.IPv4Address | ipaddress.IPv6Address
CERT_NAME = "vr-teleop.crt"
KEY_NAME = "vr-teleop.key"
CA_CERT_NAME = "vr-teleop-ca.crt"
CA_KEY_NAME = "vr-teleop-ca.key"
CA_DAYS = 3650  # an authority outlives the certificates it signs
DEFAULT_DAYS = 397  # browsers refuse longer lifetimes for server certificates (398 days at most)


@dataclass(frozen=True)
class Certificate:
    certfile: Path
    keyfile: Path
    names: tuple[str, ...]
    addresses: tuple[IPAddress, ...]
    not_after: datetime.datetime


@dataclass(frozen=True)
class Authority:
    certfile: Path
    keyfile: Path


def _write_key(keyfile: Path, key: ec.EllipticCurvePrivateKey) -> None:
    key_pem = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                serialization.NoEncryption())
    fd = os.open(keyfile, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(key_pem)
    os.chmod(keyfile, 0o600)


def make_authority(out: Path, name: str = "vr-teleop-server local authority", *, days: int = CA_DAYS) -> Authority:
    """Writes `vr-teleop-ca.crt` and `vr-teleop-ca.key` into `out`: a certificate authority that may sign server
    certificates only (path length 0). Its certificate is what clients are told to trust."""
    out.mkdir(parents=True, exist_ok=True)
    key = ec.generate_private_key(ec.SECP256R1())
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name[:64]),
                         x509.NameAttribute(NameOID.ORGANIZATION_NAME, "vr-teleop-server")])
    now = datetime.datetime.now(datetime.timezone.utc)
    cert = (
        x509.CertificateBuilder()
        .subject_name(subject).issuer_name(subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=days))
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(x509.KeyUsage(digital_signature=False, key_encipherment=False, content_commitment=False,
                                     data_encipherment=False, key_agreement=False, key_cert_sign=True,
                                     crl_sign=True, encipher_only=False, decipher_only=False), critical=True)
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
        .sign(key, hashes.SHA256())
    )
    authority = Authority(out / CA_CERT_NAME, out / CA_KEY_NAME)
    _write_key(authority.keyfile, key)
    authority.certfile.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    return authority


def machine_names() -> tuple[list[str], list[IPAddress]]:
    """The host names (short, fully qualified, .local for mDNS, localhost) and every interface address, loopback
    first; IPv6 link-local addresses (which need a zone) are left out."""
    host = socket.gethostname()
    names = [n for n in dict.fromkeys([host, socket.getfqdn(), f"{host.split('.')[0]}.local", "localhost"]) if n]
    addresses: list[IPAddress] = [ipaddress.ip_address("127.0.0.1"), ipaddress.ip_address("::1")]
    for entries in psutil.net_if_addrs().values():
        for entry in entries:
            if entry.family not in (socket.AF_INET, socket.AF_INET6):
                continue
            try:
                address = ipaddress.ip_address(entry.address.split("%", 1)[0])
            except ValueError:
                continue
            if address.is_link_local or address in addresses:
                continue
            addresses.append(address)
    return names, addresses


def lan_addresses(addresses: list[IPAddress] | tuple[IPAddress, ...]) -> list[IPAddress]:
    """The addresses a headset on the LAN could use: not loopback, IPv4 first."""
    found = [a for a in addresses if not a.is_loopback]
    return sorted(found, key=lambda a: a.version)


def make_certificate(out: Path, names: list[str], addresses: list[IPAddress], *, days: int = DEFAULT_DAYS,
                     force: bool = False, authority: Authority | None = None) -> Certificate:
    """Writes `vr-teleop.crt` and `vr-teleop.key` (PEM; the key readable by its owner only) into `out`, self-signed
    or signed by `authority` (make_authority)."""
    if not names and not addresses:
        raise ValueError("a certificate needs at least one host name or IP address")
    if not 1 <= days <= 398:
        raise ValueError(f"--days must be 1..398 (browsers refuse longer-lived certificates), not {days}")
    certfile, keyfile = out / CERT_NAME, out / KEY_NAME
    existing = [str(p) for p in (certfile, keyfile) if p.exists()]
    if existing and not force:
        raise FileExistsError(f"{', '.join(existing)} already exist; pass --force to replace them")
    out.mkdir(parents=True, exist_ok=True)
    key = ec.generate_private_key(ec.SECP256R1())
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, (names or [str(addresses[0])])[0][:64]),
                         x509.NameAttribute(NameOID.ORGANIZATION_NAME, "vr-teleop-server" if authority else
                                            "vr-teleop-server (self-signed)")])
    issuer, signer = subject, key
    if authority is not None:
        ca = x509.load_pem_x509_certificate(authority.certfile.read_bytes())
        issuer = ca.subject
        signer = serialization.load_pem_private_key(authority.keyfile.read_bytes(), password=None)
    now = datetime.datetime.now(datetime.timezone.utc)
    not_after = now + datetime.timedelta(days=days)
    san = [x509.DNSName(n) for n in names] + [x509.IPAddress(a) for a in addresses]
    builder = (
        x509.CertificateBuilder()
        .subject_name(subject).issuer_name(issuer)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))  # a headset whose clock runs a little behind
        .not_valid_after(not_after)
        .add_extension(x509.SubjectAlternativeName(san), critical=False)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(x509.KeyUsage(digital_signature=True, key_encipherment=False, content_commitment=False,
                                     data_encipherment=False, key_agreement=False, key_cert_sign=False,
                                     crl_sign=False, encipher_only=False, decipher_only=False), critical=True)
        .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
    )
    if authority is not None:
        builder = builder.add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(signer.public_key()),
                                        critical=False)
    cert = builder.sign(signer, hashes.SHA256())
    _write_key(keyfile, key)
    certfile.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    return Certificate(certfile, keyfile, tuple(names), tuple(addresses), not_after)
