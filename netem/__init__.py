"""A user-space WAN emulator: two network namespaces joined by a TUN-to-TUN forwarder that delays, jitters, drops
(randomly or in bursts), paces and reorders packets, per direction, with named profiles (profiles.yaml); around it,
optionally, the real world's edges (edges.py): NAT routers, a firewall, a port-forward and a TURN relay (relay.py).

A leaf package: it imports nothing of the server's."""

from .edges import EDGES, Edge
from .emulator import (CLIENT_IP, SERVER_IP, Emulator, NetemError, available, cleanup_leftovers, edges_available,
                       enter_netns, list_namespaces)
from .model import DIRECTIONS, Direction, DirectionParams, Profile, Stacked, load_profile, load_profiles

__all__ = ["CLIENT_IP", "DIRECTIONS", "Direction", "DirectionParams", "EDGES", "Edge", "Emulator", "NetemError",
           "Profile", "SERVER_IP", "Stacked", "available", "cleanup_leftovers", "edges_available", "enter_netns",
           "list_namespaces", "load_profile", "load_profiles"]
