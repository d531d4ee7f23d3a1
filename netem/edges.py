"""The real world's edges around the emulated WAN: a router with NAT and an egress firewall at each end, and a relay
in between, each in a namespace of its own (issue 30).

    client --LAN-- home router ==impaired link== internet --+-- relay (coturn)
                   (NAT)                                    +-- school router --LAN-- server
                                                                (NAT, firewall, port-forward)

The impaired link (the delay profile) is the TUN pair between the home router and the "internet" namespace, so a
path through the relay crosses it once, as a relay near the school would. Routers are nftables rule sets:

- NAT "cone": masquerade. Linux keeps the inside source port when it is free, so one inside socket keeps one
  outside port whoever it talks to (endpoint-independent mapping); conntrack lets in only replies from where a
  packet went (port-restricted filtering). A peer reaches it after sending first, as hole punching does.
- NAT "symmetric": masquerade random: every new destination gets a fresh outside port (endpoint-dependent mapping),
  so the port a relay or a STUN server saw is useless to anyone else.
- Firewall: outgoing UDP dropped (`block_udp`), outgoing TCP only to `tcp_ports` (None: any); replies always pass.
- Port-forward: TCP to the router's outside address on each of `forward` goes to the inside host (the school's IT
  opening the server's WebSocket port).
- Link: the inside LAN's own impairment, a profile of profiles.yaml (`home`: `wifi`, a domestic Wi-Fi's delay,
  jitter, bursty loss and rate). Only the client's edge has one: the forwarder stacks it with the delay profile
  (Wi-Fi then WAN on the way up, WAN then Wi-Fi down), since every packet of the client crosses both.

Addresses (all 10.89.x, inside our namespaces only): client 10.89.1.2 behind home 10.89.1.1 / 10.89.0.1; internet
10.89.0.2, 10.89.2.1, 10.89.3.1; relay 10.89.2.2; school 10.89.3.2 / 10.89.4.1; server 10.89.4.2.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from types import MappingProxyType
from typing import Literal

Nat = Literal["none", "cone", "symmetric"]
LAN_DEV = "lan0"


@dataclass(frozen=True)
class Edge:
    """One end's router: its NAT, its egress firewall and its forwarded TCP ports."""

    nat: Nat = "cone"
    block_udp: bool = False
    tcp_ports: tuple[int, ...] | None = None  # outgoing TCP allowed only to these ports; None: any
    forward: tuple[int, ...] = ()  # TCP ports forwarded to the inside host
    link: str | None = None  # a profile (profiles.yaml) for the inside LAN's own link, stacked with the WAN's
    doc: str = ""

    def replace(self, **changes: object) -> Edge:
        return dataclasses.replace(self, **changes)

    def ruleset(self, wan: str, inside_host: str) -> str:
        """The router's nftables rule set (nft -f), `wan` its outside device."""
        nat = {"none": "", "cone": "masquerade", "symmetric": "masquerade random"}[self.nat]
        rules = ["table ip nat {",
                 f"  chain postrouting {{ type nat hook postrouting priority srcnat; "
                 f"{f'oifname {wan!r} {nat};' if nat else ''} }}".replace("'", '"'),
                 "  chain prerouting { type nat hook prerouting priority dstnat; "
                 + "".join(f'iifname "{wan}" tcp dport {p} dnat to {inside_host}:{p}; ' for p in self.forward) + "}",
                 "}",
                 "table inet filter {",
                 "  chain forward { type filter hook forward priority 0; policy drop; "
                 "ct state established,related accept; ct status dnat accept; "
                 + ("" if self.block_udp else f'iifname "{LAN_DEV}" meta l4proto udp accept; ')
                 + (f'iifname "{LAN_DEV}" meta l4proto tcp accept; ' if self.tcp_ports is None else
                    f'iifname "{LAN_DEV}" tcp dport {{ {", ".join(map(str, self.tcp_ports))} }} accept; ')
                 + f'iifname "{LAN_DEV}" meta l4proto icmp accept; }}',
                 "}"]
        return "\n".join(rules) + "\n"


EDGES = MappingProxyType({
    "home": Edge(nat="cone", link="wifi",
                 doc="a home router: NAT (endpoint-independent mapping, port-restricted filtering), nothing "
                     "blocked; the teacher on its Wi-Fi (the `wifi` profile, stacked with the delay profile)"),
    "school": Edge(nat="symmetric", block_udp=True, tcp_ports=(80, 443), forward=(9090,),
                   doc="a school: symmetric NAT, outgoing UDP blocked, TCP out only to 80 and 443, the "
                       "server's WebSocket port (9090) forwarded to it"),
    "open": Edge(nat="none", doc="a plain router: public addresses, nothing blocked"),
})


def edge(spec: str | Edge | None) -> Edge | None:
    if spec is None or isinstance(spec, Edge):
        return spec
    if spec not in EDGES:
        raise ValueError(f"unknown edge {spec!r}; known: {', '.join(EDGES)}")
    return EDGES[spec]
