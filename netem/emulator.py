"""Two network namespaces (client, server) joined by an impaired link: real TCP and UDP stacks on both ends, the
impairment in a user-space forwarder between two TUN devices (this machine's kernel has no netem qdisc).

    with Emulator("continent") as net:
        server = net.popen("server", ["python", "-m", "http.server", "--bind", net.server_ip, "8000"])
        net.run_in("client", fetch, f"http://{net.server_ip}:8000/")   # a function run inside the client netns
        net.set(down=True)                                             # cut the link (both directions)

Safety: the only addresses are 10.89.0.1 (client) and 10.89.0.2 (server), on point-to-point TUN devices that
exist only inside the two namespaces; the namespaces have no other device but loopback and no default route, so
nothing leaves the machine. Everything is torn down on exit, also when the body raises: processes started in the
namespaces, the forwarder (its TUN devices go with it), the namespaces. Names carry a per-run prefix with the
creating process's pid (`vrnt-<pid>-<random>-client`), so `cleanup_leftovers()` can remove what a killed run left.
Needs root and /dev/net/tun.
"""

from __future__ import annotations

import contextlib
import ctypes
import json
import os
import secrets
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TypeVar

from .edges import LAN_DEV, Edge, edge
from .model import DIRECTIONS, DirectionParams, Profile, load_profile

NETNS_DIR = Path("/run/netns")
PREFIX = "vrnt-"
CLIENT_IP = "10.89.0.1"
SERVER_IP = "10.89.0.2"
CLONE_NEWNET = 0x40000000
PR_SET_PDEATHSIG = 1
SIDES = ("client", "server")
# With edges (edges.py): the routers, the internet between them and the relay, and who holds each TUN end
EDGE_NAMESPACES = ("client", "home", "internet", "relay", "school", "server")
EDGE_ADDRESSES = {"client": "10.89.1.2", "home_lan": "10.89.1.1", "home_wan": CLIENT_IP, "internet": SERVER_IP,
                  "internet_relay": "10.89.2.1", "relay": "10.89.2.2", "internet_school": "10.89.3.1",
                  "school_wan": "10.89.3.2", "school_lan": "10.89.4.1", "server": "10.89.4.2"}
WAN_DEV = "wan0"
T = TypeVar("T")


class NetemError(RuntimeError):
    pass


def edges_available() -> str | None:
    """None when the edges (NAT, firewall: nftables) and the relay (coturn) can run here, else why not."""
    import shutil

    why = available()
    if why:
        return why
    for tool, package in (("nft", "nftables"), ("turnserver", "coturn")):
        if shutil.which(tool) is None:
            return f"the emulator's edges need {tool} (Debian's {package}; scripts/install-system-packages.sh)"
    return None


def available() -> str | None:
    """None when the emulator can run here, else why not (for a skip reason)."""
    if os.geteuid() != 0:
        return "the network emulator needs root (it creates network namespaces and TUN devices)"
    if not os.path.exists("/dev/net/tun"):
        return "the network emulator needs /dev/net/tun (TUN devices)"
    if subprocess.run(["ip", "netns", "list"], capture_output=True).returncode != 0:
        return "the network emulator needs iproute2 with `ip netns`"
    return None


def _ip(*args: str, check: bool = True) -> subprocess.CompletedProcess[str]:
    done = subprocess.run(["ip", *args], capture_output=True, text=True)
    if check and done.returncode != 0:
        raise NetemError(f"ip {' '.join(args)}: {done.stderr.strip() or done.returncode}")
    return done


def list_namespaces(prefix: str = PREFIX) -> list[str]:
    out = _ip("netns", "list").stdout
    return [line.split()[0] for line in out.splitlines() if line.startswith(prefix)]


def _pids_in(ns: str) -> list[int]:
    done = _ip("netns", "pids", ns, check=False)
    return [int(p) for p in done.stdout.split()] if done.returncode == 0 else []


def _kill_namespace(ns: str) -> None:
    """Stops every process inside our namespace `ns` (TERM, then KILL), then deletes it."""
    for sig, wait in ((signal.SIGTERM, 3.0), (signal.SIGKILL, 2.0)):
        pids = _pids_in(ns)
        if not pids:
            break
        for pid in pids:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, sig)
        deadline = time.monotonic() + wait
        while time.monotonic() < deadline and _pids_in(ns):
            time.sleep(0.05)
    _ip("netns", "del", ns, check=False)


def cleanup_leftovers(all_runs: bool = False) -> list[str]:
    """Removes the namespaces (and the processes in them) of runs whose creating process is gone (or, with
    `all_runs`, of every run). Returns the names removed. TUN devices need no cleanup: they live only as long as
    their forwarder, which exits when its parent does."""
    removed = []
    for ns in list_namespaces():
        try:
            pid = int(ns[len(PREFIX):].split("-")[0])
        except ValueError:
            continue
        if not all_runs and Path(f"/proc/{pid}").exists():
            continue  # its run is still going (or it is ours: close() removes those)
        _kill_namespace(ns)
        removed.append(ns)
    return removed


def _run_in_ns(ns: str, argv: list[str], stdin: str | None = None) -> None:
    done = subprocess.run(["ip", "netns", "exec", ns, *argv], input=stdin, capture_output=True, text=True)
    if done.returncode != 0:
        raise NetemError(f"{' '.join(argv)} in {ns}: {done.stderr.strip() or done.returncode}")


def _die_with_parent() -> None:
    """In the child before exec: SIGTERM when the process that started it dies (even by SIGKILL)."""
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)


def enter_netns(name: str) -> None:
    """Moves the CALLING THREAD into network namespace `name` (a thread's namespace is its own: sockets it
    creates from now on belong there, wherever they are used later)."""
    libc = ctypes.CDLL(None, use_errno=True)
    fd = os.open(NETNS_DIR / name, os.O_RDONLY)
    try:
        if libc.setns(fd, CLONE_NEWNET) != 0:
            err = ctypes.get_errno()
            raise OSError(err, f"setns({name}): {os.strerror(err)}")
    finally:
        os.close(fd)


class Emulator:
    """The two namespaces and the impaired link between them (see the module docstring); with `client_edge` or
    `server_edge` (an edges.Edge or its name: "home", "school", "open"), the routers, the internet and a relay
    namespace around them (edges.py). `server_ip` is the address the server binds; `public_ip` the one clients
    dial (the school router's, whose forwarded ports reach the server); `relay_ip` the relay's (start_relay)."""

    def __init__(self, profile: str | Profile = "lan", *, seed: int | None = None, python: str = sys.executable,
                 profiles_file: Path | None = None, client_edge: str | Edge | None = None,
                 server_edge: str | Edge | None = None) -> None:
        self.profile = profile if isinstance(profile, Profile) else load_profile(profile, profiles_file)
        self.seed = seed
        self.python = python
        run = f"{PREFIX}{os.getpid()}-{secrets.token_hex(3)}"
        self.edges = None
        if client_edge is not None or server_edge is not None:
            self.edges = {"home": edge(client_edge or "open"), "school": edge(server_edge or "open")}
        self.netns = {side: f"{run}-{side}" for side in (EDGE_NAMESPACES if self.edges else SIDES)}
        tag = run.split("-")[-1]
        self.tun = {side: f"vrnt{tag}{side[0]}" for side in SIDES}  # <= 15 characters
        self.client_ip, self.server_ip = CLIENT_IP, SERVER_IP
        self.public_ip, self.relay_ip = SERVER_IP, None
        self._tun_ns = {side: self.netns[side] for side in SIDES}  # which namespace holds each TUN end
        if self.edges:
            a = EDGE_ADDRESSES
            self.client_ip, self.server_ip, self.public_ip, self.relay_ip = (a["client"], a["server"],
                                                                             a["school_wan"], a["relay"])
            self._tun_ns = {"client": self.netns["home"], "server": self.netns["internet"]}
        self.params = {d: self.profile.direction(d) for d in DIRECTIONS}
        self.link: Profile | None = None  # the client edge's own link, stacked with the profile (edges.py)
        if self.edges:
            if self.edges["school"].link:
                raise ValueError("only the client's edge can have a link of its own (server_edge "
                                 f"{self.edges['school'].link!r}): the relay's path does not cross the school's")
            if self.edges["home"].link:
                self.link = load_profile(self.edges["home"].link, profiles_file)
        self._forwarder: subprocess.Popen[str] | None = None
        self._procs: list[subprocess.Popen[Any]] = []
        self._lock = threading.Lock()  # one command at a time on the forwarder's pipe

    # ---- lifetime ---------------------------------------------------------------------------------------------
    def __enter__(self) -> Emulator:
        try:
            self.start()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def start(self) -> None:
        for ns in self.netns.values():
            _ip("netns", "add", ns)
            _ip("-n", ns, "link", "set", "lo", "up")
        spec = {"tun": self.tun, "netns": self._tun_ns, "seed": self.seed,
                "params": {d: p.to_dict() for d, p in self.params.items()},
                "link": {d: self.link.direction(d).to_dict() for d in DIRECTIONS} if self.link else None}
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(Path(__file__).parent.parent),
                                                                          os.environ.get("PYTHONPATH")]))}
        self._forwarder = subprocess.Popen([self.python, "-m", "netem.forwarder", json.dumps(spec)],
                                           stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env,
                                           preexec_fn=_die_with_parent)
        line = self._forwarder.stdout.readline()
        if not line or not json.loads(line).get("ready"):
            raise NetemError(f"the forwarder did not start (exit code {self._forwarder.poll()})")
        peers = {"client": (CLIENT_IP, SERVER_IP), "server": (SERVER_IP, CLIENT_IP)}
        for side in SIDES:
            local, peer = peers[side]
            ns, dev = self._tun_ns[side], self.tun[side]
            _ip("-n", ns, "addr", "add", local, "peer", peer, "dev", dev)
            _ip("-n", ns, "link", "set", dev, "txqueuelen", "10000", "up")
        if self.edges:
            self._build_edges()

    def _veth(self, a: str, a_dev: str, a_ip: str, b: str, b_dev: str, b_ip: str) -> None:
        """A /24 link between namespaces a and b (created inside them: nothing in the host's namespace)."""
        _ip("-n", self.netns[a], "link", "add", a_dev, "type", "veth", "peer", "name", b_dev, "netns", self.netns[b])
        for ns, dev, addr in ((a, a_dev, a_ip), (b, b_dev, b_ip)):
            _ip("-n", self.netns[ns], "addr", "add", f"{addr}/24", "dev", dev)
            _ip("-n", self.netns[ns], "link", "set", dev, "up")

    def _build_edges(self) -> None:
        a = EDGE_ADDRESSES
        self._veth("client", LAN_DEV, a["client"], "home", LAN_DEV, a["home_lan"])
        self._veth("internet", "relay0", a["internet_relay"], "relay", WAN_DEV, a["relay"])
        self._veth("internet", "school0", a["internet_school"], "school", WAN_DEV, a["school_wan"])
        self._veth("school", LAN_DEV, a["school_lan"], "server", LAN_DEV, a["server"])
        routes = {"client": [["default", "via", a["home_lan"]]], "home": [["default", "dev", self.tun["client"]]],
                  "relay": [["default", "via", a["internet_relay"]]], "school": [["default", "via", a["internet_school"]]],
                  "server": [["default", "via", a["school_lan"]]],
                  # the inside networks are routed to their routers, which drop what no mapping or forward lets in
                  "internet": [["10.89.1.0/24", "dev", self.tun["server"]], ["10.89.4.0/24", "via", a["school_wan"]]]}
        for ns, entries in routes.items():
            for route in entries:
                _ip("-n", self.netns[ns], "route", "add", *route)
        for router, wan, inside in (("home", self.tun["client"], a["client"]), ("school", WAN_DEV, a["server"])):
            _run_in_ns(self.netns[router], ["sysctl", "-qw", "net.ipv4.ip_forward=1"])
            _run_in_ns(self.netns[router], ["nft", "-f", "-"], self.edges[router].ruleset(wan, inside))
        _run_in_ns(self.netns["internet"], ["sysctl", "-qw", "net.ipv4.ip_forward=1"])

    def close(self) -> None:
        """Everything goes, in an order that cannot leave a device or process behind; safe to call twice."""
        for proc in self._procs:
            if proc.poll() is None:
                proc.terminate()
        for proc in self._procs:
            try:
                proc.wait(5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(5)
        self._procs.clear()
        if self._forwarder is not None:
            with contextlib.suppress(OSError):
                self._forwarder.stdin.close()
            try:
                self._forwarder.wait(5)
            except subprocess.TimeoutExpired:
                self._forwarder.kill()
                self._forwarder.wait(5)
            with contextlib.suppress(OSError):
                self._forwarder.stdout.close()
            self._forwarder = None
        for ns in self.netns.values():
            if (NETNS_DIR / ns).exists():
                _kill_namespace(ns)

    # ---- the link ---------------------------------------------------------------------------------------------
    def _command(self, msg: dict[str, Any]) -> dict[str, Any]:
        if self._forwarder is None or self._forwarder.poll() is not None:
            raise NetemError("the forwarder is not running")
        with self._lock:
            self._forwarder.stdin.write(json.dumps(msg) + "\n")
            self._forwarder.stdin.flush()
            reply = json.loads(self._forwarder.stdout.readline() or "{}")
        if not reply.get("ok"):
            raise NetemError(reply.get("error", "the forwarder did not answer"))
        return reply

    def set(self, direction: str = "both", **changes: Any) -> None:
        """Changes some impairment keys (profiles.yaml) of one direction ("up": client -> server, "down") or
        both, e.g. set(down=True) cuts the link, set(loss=0.1, direction="up")."""
        for d in DIRECTIONS if direction == "both" else (direction,):
            if d not in DIRECTIONS:
                raise ValueError(f"direction must be up, down or both, not {direction!r}")
            params = self.params[d].replace(**changes)
            self._command({"cmd": "set", "direction": d, "params": params.to_dict()})
            self.params[d] = params

    def set_params(self, direction: str, params: DirectionParams) -> None:
        self._command({"cmd": "set", "direction": direction, "params": params.to_dict()})
        for d in DIRECTIONS if direction == "both" else (direction,):
            self.params[d] = params

    def stats(self, late_samples: bool = False) -> dict[str, Any]:
        """Per direction ("stats": the profile's; "link": the client edge's own link, if any): packets, delivered,
        lost, queue_dropped, cut, reordered; "late_ms", how late the forwarder's timed writes ran since the last
        call (and with `late_samples`, each of them in "late_s", seconds: the host's share of what a probe sees)."""
        return self._command({"cmd": "stats", "late_samples": late_samples})

    @property
    def forwarder_pid(self) -> int | None:
        return self._forwarder.pid if self._forwarder is not None else None

    def set_edge(self, router: str, spec: str | Edge) -> None:
        """Replaces the rule set of the "home" or "school" router (e.g. the school starts letting UDP out)."""
        if not self.edges or router not in self.edges:
            raise NetemError(f"no router {router!r}: the edges are home and school (give client_edge/server_edge)")
        new = edge(spec)
        wan, inside = ((self.tun["client"], EDGE_ADDRESSES["client"]) if router == "home"
                       else (WAN_DEV, EDGE_ADDRESSES["server"]))
        _run_in_ns(self.netns[router], ["nft", "-f", "-"], "flush ruleset\n" + new.ruleset(wan, inside))
        self.edges[router] = new

    # ---- the relay ----------------------------------------------------------------------------------------------
    def start_relay(self, secret: str, certfile: Path, keyfile: Path, workdir: Path,
                    timeout: float = 30.0) -> subprocess.Popen[Any]:
        """coturn (Debian's turnserver) in the relay namespace with relay.coturn_config; returns once it accepts
        TCP on 3478 and 443. Its log is workdir/turnserver.log; it is stopped (by its pid) on close()."""
        from .relay import PORT, TLS_PORT, coturn_config

        if self.relay_ip is None:
            raise NetemError("a relay needs the edges: give client_edge and/or server_edge")
        log_file = workdir / "turnserver.log"
        conf = workdir / "turnserver.conf"
        conf.write_text(coturn_config(self.relay_ip, secret, certfile, keyfile, log_file))
        conf.chmod(0o600)
        proc = self.popen("relay", ["turnserver", "-c", str(conf), "--pidfile", str(workdir / "turnserver.pid")],
                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

        def listening() -> bool:
            import socket
            for port in (PORT, TLS_PORT):
                with socket.socket() as s:
                    s.settimeout(1.0)
                    if s.connect_ex((self.relay_ip, port)) != 0:
                        return False
            return True

        deadline = time.monotonic() + timeout
        while not self.run_in("relay", listening):
            if proc.poll() is not None or time.monotonic() > deadline:
                raise NetemError(f"coturn did not start in the relay namespace (exit {proc.poll()}): "
                                 f"{log_file.read_text()[-1500:] if log_file.exists() else 'no log'}")
            time.sleep(0.1)
        return proc

    # ---- running things inside ----------------------------------------------------------------------------------
    def popen(self, side: str, argv: Sequence[str], **kwargs: Any) -> subprocess.Popen[Any]:
        """Starts a command inside the client's or the server's namespace; it is stopped on close() (and gets
        SIGTERM if this process dies)."""
        proc = subprocess.Popen(["ip", "netns", "exec", self.netns[side], *argv], preexec_fn=_die_with_parent,
                                **kwargs)
        self._procs.append(proc)
        return proc

    def run_in(self, side: str, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        """Calls fn(*args) in a thread inside the side's namespace and returns its result (or raises its error).
        Sockets fn creates belong to that namespace; an asyncio.run inside fn keeps all its sockets there."""
        result: dict[str, Any] = {}

        def target() -> None:
            try:
                enter_netns(self.netns[side])
                result["value"] = fn(*args, **kwargs)
            except BaseException as exc:  # handed to the caller
                result["error"] = exc

        thread = threading.Thread(target=target, name=f"netns-{side}", daemon=True)
        thread.start()
        thread.join()
        if "error" in result:
            raise result["error"]
        return result["value"]

    def start_in(self, side: str, fn: Callable[..., Any], *args: Any) -> threading.Thread:
        """Like run_in, without waiting: the thread is returned (join it)."""
        def target() -> None:
            enter_netns(self.netns[side])
            fn(*args)

        thread = threading.Thread(target=target, name=f"netns-{side}", daemon=True)
        thread.start()
        return thread
