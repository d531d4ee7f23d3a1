"""A user-space WAN emulator: two network namespaces joined by a TUN-to-TUN forwarder that delays, jitters, drops
(randomly or in bursts), paces and reorders packets, per direction, with named profiles (profiles.yaml).

A leaf package: it imports nothing of the server's."""

from .emulator import CLIENT_IP, SERVER_IP, Emulator, NetemError, available, cleanup_leftovers, enter_netns
from .model import DIRECTIONS, Direction, DirectionParams, Profile, load_profile, load_profiles

__all__ = ["CLIENT_IP", "DIRECTIONS", "Direction", "DirectionParams", "Emulator", "NetemError", "Profile",
           "SERVER_IP", "available", "cleanup_leftovers", "enter_netns", "load_profile", "load_profiles"]
