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

from .model import DIRECTIONS, DirectionParams, Profile, load_profile

NETNS_DIR = Path("/run/netns")
PREFIX = "vrnt-"
CLIENT_IP = "10.89.0.1"
SERVER_IP = "10.89.0.2"
CLONE_NEWNET = 0x40000000
PR_SET_PDEATHSIG = 1
SIDES = ("client", "server")
T = TypeVar("T")


class NetemError(RuntimeError):
    pass


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
    """The two namespaces and the impaired link between them (see the module docstring)."""

    def __init__(self, profile: str | Profile = "lan", *, seed: int | None = None, python: str = sys.executable,
                 profiles_file: Path | None = None) -> None:
        self.profile = profile if isinstance(profile, Profile) else load_profile(profile, profiles_file)
        self.seed = seed
        self.python = python
        run = f"{PREFIX}{os.getpid()}-{secrets.token_hex(3)}"
        self.netns = {side: f"{run}-{side}" for side in SIDES}
        tag = run.split("-")[-1]
        self.tun = {side: f"vrnt{tag}{side[0]}" for side in SIDES}  # <= 15 characters
        self.client_ip, self.server_ip = CLIENT_IP, SERVER_IP
        self.params = {d: self.profile.direction(d) for d in DIRECTIONS}
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
        for side in SIDES:
            _ip("netns", "add", self.netns[side])
            _ip("-n", self.netns[side], "link", "set", "lo", "up")
        spec = {"tun": self.tun, "netns": self.netns, "seed": self.seed,
                "params": {d: p.to_dict() for d, p in self.params.items()}}
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
            ns, dev = self.netns[side], self.tun[side]
            _ip("-n", ns, "addr", "add", local, "peer", peer, "dev", dev)
            _ip("-n", ns, "link", "set", dev, "txqueuelen", "10000", "up")

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
        for side in SIDES:
            if (NETNS_DIR / self.netns[side]).exists():
                _kill_namespace(self.netns[side])

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

    def stats(self) -> dict[str, Any]:
        """Per direction: packets, delivered, lost, queue_dropped, cut, reordered."""
        return self._command({"cmd": "stats"})

    @property
    def forwarder_pid(self) -> int | None:
        return self._forwarder.pid if self._forwarder is not None else None

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
