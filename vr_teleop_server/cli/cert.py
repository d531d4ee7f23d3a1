"""`vr-teleop cert --out DIR`: a self-signed certificate and key for https:// and wss:// on the classroom LAN
(WebXR and the microphone need a secure context). With `--ca DIR`, signed by a local authority instead (made there
the first time), whose certificate a school installs once on its headsets and browsers: what a `turns:` relay
needs, since browsers accept no self-signed certificate there."""

from __future__ import annotations

import argparse
import ipaddress
import sys
from pathlib import Path

from ..core.certs import CA_CERT_NAME, CA_KEY_NAME, Authority, lan_addresses, machine_names, make_authority, \
    make_certificate


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "cert", help="write a self-signed TLS certificate for this machine (https/wss for headsets)",
        description="Write a self-signed certificate (vr-teleop.crt) and key (vr-teleop.key) naming this "
                    "machine's host names and IP addresses, for `serve --certfile --keyfile`.")
    p.add_argument("--out", required=True, type=Path, help="directory to write the two files into")
    p.add_argument("--name", action="append", default=[], metavar="HOST",
                   help="a further host name to include (repeatable)")
    p.add_argument("--ip", action="append", default=[], metavar="ADDRESS",
                   help="a further IP address to include (repeatable), e.g. the router's forwarded address")
    p.add_argument("--days", type=int, default=397, help="validity in days (at most 398; default 397)")
    p.add_argument("--force", action="store_true", help="replace existing files")
    p.add_argument("--ca", type=Path, default=None, metavar="DIR",
                   help=f"sign with the local authority in DIR ({CA_CERT_NAME}, {CA_KEY_NAME}; made there if "
                        "absent) instead of self-signing; install its certificate on the clients")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    names, addresses = machine_names()
    try:
        extra = [ipaddress.ip_address(a) for a in args.ip]
    except ValueError as exc:
        print(f"vr-teleop cert: --ip: {exc}", file=sys.stderr)
        return 2
    names += [n for n in args.name if n not in names]
    addresses += [a for a in extra if a not in addresses]
    try:
        authority = None
        if args.ca is not None:
            authority = Authority(args.ca / CA_CERT_NAME, args.ca / CA_KEY_NAME)
            if not authority.certfile.exists():
                authority = make_authority(args.ca)
                print(f"wrote the authority {authority.certfile} (install it on the clients) and its key "
                      f"{authority.keyfile} (keep it private)")
        cert = make_certificate(args.out, names, addresses, days=args.days, force=args.force, authority=authority)
    except (OSError, ValueError) as exc:
        print(f"vr-teleop cert: {exc}", file=sys.stderr)
        return 1
    print(f"wrote {cert.certfile} and {cert.keyfile} (valid until {cert.not_after:%Y-%m-%d})")
    print(f"  names:     {', '.join(cert.names)}")
    print(f"  addresses: {', '.join(map(str, cert.addresses))}")
    print(f"serve with:  vr-teleop serve --host 0.0.0.0 --certfile {cert.certfile} --keyfile {cert.keyfile} "
          "--generate-tokens")
    for address in lan_addresses(cert.addresses)[:3]:
        host = f"[{address}]" if address.version == 6 else str(address)
        print(f"headset:     https://{host}:9090/operator  (accept the certificate once)")
    return 0
