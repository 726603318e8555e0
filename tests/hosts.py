"""Separate hosts on one machine, for the multi-host tests: one network namespace per host
(its own addresses and ports), joined by veth pairs to a bridge in a namespace of its own
(nothing is added to the machine's own network), and a private mount namespace per process
with a fresh tmpfs over the run's disk folder (:attr:`Hosts.disk`, a new empty folder, so it
can hide nothing the processes need: the checkout and its venv may well lie under /tmp)
holding its HOME and TMPDIR (so no two hosts share a disk: only the installed software is
common, as on real machines).

Everything is named with a random tag per run and removed by :meth:`Hosts.close`: every
process in each namespace is killed (``ip netns pids``), then the namespaces go, and
their veths with them. Needs root, ``ip`` (iproute2) and ``unshare`` (util-linux).
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import tempfile
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

#: The private range used only inside the namespaces (never on the machine's interfaces).
SUBNET = "10.213.7"

#: Run in each process's new mount namespace (``$0``: the disk folder): a private tmpfs there,
#: HOME and TMPDIR inside it.
PRIVATE_DISK = (
    'mount -t tmpfs -o size=2g,mode=1777 tmpfs "$0" && mkdir -p "$0/home" && cd "$0/home" && '
    'HOME="$0/home" TMPDIR="$0" exec "$@"'
)


def missing_tools() -> str | None:
    """Why separate hosts cannot be made here, or None."""
    if os.geteuid() != 0:
        return "separate hosts need root (network and mount namespaces)"
    for tool, package in (("ip", "iproute2"), ("unshare", "util-linux")):
        if shutil.which(tool) is None:
            return f"separate hosts need `{tool}` (apt-get install {package})"
    probe = f"dyprobe{uuid.uuid4().hex[:6]}"
    made = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True)
    if made.returncode != 0:
        return f"cannot make a network namespace here: {made.stderr.strip()[:120]}"
    subprocess.run(["ip", "netns", "del", probe], capture_output=True)
    return None


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, text=True)


@dataclass
class Host:
    name: str
    netns: str
    address: str


class Hosts:
    """A set of hosts on one bridge; processes started on them; all of it removed by close()."""

    def __init__(self, logs: Path) -> None:
        self.tag = f"dy{uuid.uuid4().hex[:6]}"
        self.bridge = f"{self.tag}-br"
        self.logs = logs
        self.hosts: dict[str, Host] = {}
        self.procs: list[subprocess.Popen] = []
        #: Each process's private disk is a tmpfs mounted here in its own mount namespace.
        self.disk = Path(tempfile.mkdtemp(prefix=f"{self.tag}-disk-"))
        _ip("netns", "add", self.bridge)
        _ip("-n", self.bridge, "link", "add", "br0", "type", "bridge")
        _ip("-n", self.bridge, "link", "set", "br0", "up")

    def add(self, name: str) -> Host:
        index = len(self.hosts) + 1
        host = Host(name, f"{self.tag}-{name}", f"{SUBNET}.{index}")
        _ip("netns", "add", host.netns)
        self.hosts[name] = host
        _ip("link", "add", "eth0", "netns", host.netns, "type", "veth", "peer", "name", f"h{index}",
            "netns", self.bridge)
        _ip("-n", self.bridge, "link", "set", f"h{index}", "master", "br0", "up")
        _ip("-n", host.netns, "addr", "add", f"{host.address}/24", "dev", "eth0")
        _ip("-n", host.netns, "link", "set", "eth0", "up")
        _ip("-n", host.netns, "link", "set", "lo", "up")
        return host

    def _argv(self, name: str, argv: list[str]) -> list[str]:
        return ["ip", "netns", "exec", self.hosts[name].netns, "unshare", "--mount", "--propagation", "private",
                "sh", "-c", PRIVATE_DISK, str(self.disk), *argv]

    def start(self, name: str, argv: list[str], env: dict[str, str], log: str) -> subprocess.Popen:
        """Start ``argv`` on host ``name`` (output to ``logs/<log>``)."""
        with open(self.logs / log, "ab") as out:
            proc = subprocess.Popen(self._argv(name, argv), env=env, stdout=out, stderr=subprocess.STDOUT,
                                    stdin=subprocess.DEVNULL, start_new_session=True)
        self.procs.append(proc)
        return proc

    def run(self, name: str, argv: list[str], env: dict[str, str], timeout: float) -> subprocess.CompletedProcess:
        """Run ``argv`` on host ``name`` to its end."""
        return subprocess.run(self._argv(name, argv), env=env, capture_output=True, text=True, timeout=timeout,
                              stdin=subprocess.DEVNULL)

    def pids(self, name: str) -> list[int]:
        found = subprocess.run(["ip", "netns", "pids", self.hosts[name].netns], capture_output=True, text=True)
        return [int(pid) for pid in found.stdout.split()]

    def kill(self, name: str) -> list[int]:
        """SIGKILL every process on host ``name`` (a host lost at once); the pids killed."""
        pids = self.pids(name)
        for pid in pids:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        for proc in self.procs:
            if proc.pid in pids:
                proc.wait(timeout=30)
        deadline = time.monotonic() + 10
        while self.pids(name) and time.monotonic() < deadline:
            time.sleep(0.05)
        return pids

    def wait_for_log(self, log: str, pattern: str, proc: subprocess.Popen, timeout: float) -> re.Match:
        """The first match of ``pattern`` in ``logs/<log>``, waiting for it while ``proc`` runs."""
        deadline = time.monotonic() + timeout
        while True:
            found = re.search(pattern, (self.logs / log).read_text(errors="replace"))
            if found:
                return found
            if proc.poll() is not None or time.monotonic() > deadline:
                tail = (self.logs / log).read_text(errors="replace")[-2000:]
                raise AssertionError(f"{log}: no {pattern!r} (exit {proc.poll()}):\n{tail}")
            time.sleep(0.1)

    def close(self) -> None:
        """Kill every process on every host, then remove the namespaces (and their veths)."""
        for name in self.hosts:
            self.kill(name)
        for proc in self.procs:
            if proc.poll() is None:
                proc.kill()
            proc.wait(timeout=30)
        for netns in [host.netns for host in self.hosts.values()] + [self.bridge]:
            subprocess.run(["ip", "netns", "del", netns], capture_output=True)
        self.hosts.clear()
        shutil.rmtree(self.disk, ignore_errors=True)

    def leftovers(self) -> list[str]:
        """Namespaces of this run still present (none after close())."""
        listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
        return [line.split()[0] for line in listed.splitlines() if line.startswith(self.tag)]
