#!/usr/bin/env bash
# Installs the Debian packages the project needs, only those missing. Runs as root (or via sudo where present).
set -euo pipefail
needed=(espeak-ng libegl1 libegl-mesa0 libgl1-mesa-dri libgles2 libgl1 chromium openssl nodejs iproute2 mosquitto nftables coturn libnss3-tools faketime)  # iproute2: `ip netns`, nftables: NAT and firewall (netem); coturn: the TURN relay; libnss3-tools: certutil (a browser trusting a local authority), faketime: a server clock behind (tests/test_nat_turn.py); libgl1: opencv-python's GUI build loads it (and GLib and X11's libraries, which chromium brings)
missing=()
for p in "${needed[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
command -v npm >/dev/null || missing+=(npm)  # Debian's npm; NodeSource's nodejs brings its own
[ ${#missing[@]} -eq 0 ] && exit 0
sudo=""; [ "$(id -u)" -ne 0 ] && sudo="sudo"
export DEBIAN_FRONTEND=noninteractive
$sudo apt-get update -qq
$sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"
