"""A sealed policy process: what a held-out run (``--test-seed``) runs a ``module:callable`` in.

An organiser evaluating a submitted policy on a private split must keep the secret from
the policy (threat model: docs/guides/evaluate.md, "Sealed held-out runs"). The policy's
process (:class:`pipeline.remote.isolated.IsolatedPolicy`, under its launcher) is started
by util-linux ``unshare`` in new user, PID, mount, network, IPC and UTS namespaces:

- PID: ``/proc`` is remounted and shows the sandbox's own processes only: no driver's or
  worker's command line, environment, open files or memory;
- mount: the home folders (``/root``, ``/home``, ``$HOME``), ``/tmp``, ``/var/tmp``,
  ``/dev/shm``, ``/run``, the run folder and the folder of ``--test-seed-file`` are
  covered by empty tmpfs (the only places it may write: every other mount is made
  read-only, so it can change no file a worker or the driver later reads or imports);
  the Python install and the folders it imports from (``sys.path``) are bound back,
  and the secret file itself is covered by ``/dev/null`` last. Then a second user
  namespace without root locks every mount (none can be undone) and drops every
  capability (``no_new_privs`` too);
- network: a namespace of its own (no host ``127.0.0.1``: no Dask scheduler, no local
  service); the worker reaches the policy through a listening socket it made on the
  host's loopback and passed in (``--pass-fd``), the only descriptor the policy inherits;
- environment: ``PATH``, ``PYTHONPATH``, ``LANG`` and ``HOME=/tmp`` only.

Where the machine cannot provide the namespaces (no ``unshare``, unprivileged user
namespaces turned off) a sealed run is refused before any work (:func:`check_available`).
"""

from __future__ import annotations

import ctypes
import json
import os
import re
import selectors
import shutil
import socket
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache

from schemas.errors import PolicyError, SpecError
from schemas.names import printable

#: Folders every sealed policy loses (besides the run folder and the secret file's folder).
HIDDEN = ("/tmp", "/var/tmp", "/dev/shm", "/run", "/root", "/home")
UNSHARE_FLAGS = ("--user", "--map-root-user", "--pid", "--mount", "--net", "--ipc", "--uts", "--fork",
                 "--kill-child", "--mount-proc")
CLONE_NEWNS = 0x00020000
CLONE_NEWUSER = 0x10000000
MS_RDONLY, MS_NOSUID, MS_NODEV, MS_REMOUNT, MS_BIND, MS_REC = 1, 2, 4, 32, 4096, 16384
PR_SET_NO_NEW_PRIVS = 38
#: Seconds the probe of :func:`check_available` may take.
PROBE_TIMEOUT_S = 20.0
#: The module run inside the sandbox: it serves the policy, or prints its configuration.
INSIDE = "pipeline.sealed_main"
#: Seconds a sealed configuration (:func:`configured`: loading a model once) may take.
CONFIGURE_TIMEOUT_S = 300.0
#: The most a sealed configuration may print (a manifest's key, not a data channel).
MAX_CONFIG_BYTES = 64 << 10


@dataclass(frozen=True)
class Seal:
    """What a sealed policy must not see besides :data:`HIDDEN`: folders (the run's, the
    secret file's) covered by tmpfs, files (the secret file) covered by ``/dev/null``; and
    the files it must still read (``shown``: a saved model), bound back read-only."""

    folders: tuple[str, ...] = ()
    files: tuple[str, ...] = ()
    shown: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        for path in (*self.folders, *self.files, *self.shown):
            if not isinstance(path, str) or not os.path.isabs(path) or "\0" in path:
                raise SpecError(f"sealed run: {path!r} is not an absolute path")


def seal_for(secret_file: str | None, run_folder: str | None, shown: tuple[str, ...] = ()) -> Seal:
    """The seal of a held-out run: the run folder and the secret file (and its folder)
    hidden, the policy's own files (``shown``) readable (the secret stays covered even there)."""
    folders = [os.path.realpath(run_folder)] if run_folder else []
    files = []
    if secret_file not in (None, "-"):  # "-": read from stdin, which the policy never gets
        real = os.path.realpath(secret_file)
        folders.append(os.path.dirname(real))
        files.append(real)
    return Seal(tuple(folders), tuple(files), tuple(os.path.realpath(p) for p in shown))


def sealing(shown: tuple[str, ...] | None, private: object, isolate: bool, secret_file: str | None,
            run_folder: str | None) -> Seal | None:
    """The seal of a run whose policy runs a user's code (a ``module:callable``, or a saved
    model that unpickles code when loaded) and reads the files ``shown``: on a private split
    it runs sealed (refused in process, or where the machine cannot seal it). None for a
    public run, or a policy that runs no user's code (``shown`` None)."""
    if private is None or shown is None:
        return None
    if not isolate:
        raise SpecError("a private test seed runs a user's policy code sealed in a child process; "
                        "--in-process would run it beside the secret")
    check_available()
    return seal_for(secret_file, run_folder, shown)


def unshare_path() -> str | None:
    return shutil.which("unshare")


@cache
def _probe(unshare: str) -> str | None:
    """None if ``unshare`` seals a process here (the whole seal, around ``python -c pass``), else why not."""
    try:
        done = subprocess.run(_sealed(unshare, Seal(), [sys.executable, "-S", "-c", "pass"]), stdin=subprocess.DEVNULL,
                              capture_output=True, timeout=PROBE_TIMEOUT_S, check=False, env=environment())
    except (OSError, subprocess.TimeoutExpired) as exc:
        return str(exc)
    if done.returncode != 0:
        text = done.stderr.decode("utf-8", "replace").strip()
        return printable(text.splitlines()[0], 200) if text else f"exit {done.returncode}"
    return None


def unavailable() -> str | None:
    """None where this machine can seal a policy, else why not."""
    unshare = unshare_path()
    return "util-linux unshare is not on PATH" if unshare is None else _probe(unshare)


def check_available() -> str:
    """The ``unshare`` command to seal a policy with; SpecError (one line) where the machine cannot."""
    why = unavailable()
    unshare = unshare_path()
    if unshare is None or why is not None:
        raise SpecError(
            f"a private test seed runs a module:callable policy sealed (its own user, PID, mount and network "
            f"namespaces), and this machine cannot: {why}; run it on a machine with util-linux unshare and "
            "unprivileged user namespaces, or serve the policy elsewhere and evaluate it as ws://HOST:PORT"
        )
    return unshare


def _sealed(unshare: str, seal: Seal, argv: list[str]) -> list[str]:
    """``argv`` run sealed by ``unshare`` (module docstring)."""
    spec = {"folders": list(seal.folders), "files": list(seal.files), "home": os.path.expanduser("~"),
            "keep": [os.path.realpath(p or os.getcwd()) for p in (*sys.path, sys.prefix, sys.base_prefix, sys.exec_prefix,
                                                                  os.path.dirname(os.path.realpath(sys.executable)),
                                                                  *seal.shown)]}
    return [unshare, *UNSHARE_FLAGS, sys.executable, "-m", "pipeline.remote.sandbox", json.dumps(spec), "--", *argv]


def command(seal: Seal, ref: str, fd: int) -> list[str]:
    """The command that serves ``ref`` sealed, on the listening socket ``fd``."""
    return _sealed(check_available(), seal, [sys.executable, "-m", INSIDE, "serve", ref, str(fd)])


def environment() -> dict[str, str]:
    """The sealed policy's whole environment."""
    return {"PATH": "/usr/local/bin:/usr/bin:/bin", "LANG": "C.UTF-8", "HOME": "/tmp",
            "PYTHONPATH": os.pathsep.join(os.path.realpath(p or os.getcwd()) for p in sys.path)}


def listening_socket() -> socket.socket:
    """A socket listening on the host's 127.0.0.1 (any port), to pass into the sandbox."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.bind(("127.0.0.1", 0))
    sock.listen(4)
    sock.set_inheritable(True)
    return sock


def _libc() -> ctypes.CDLL:
    return ctypes.CDLL(None, use_errno=True)


def _mount(libc: ctypes.CDLL, source: str, target: str, fstype: str | None, flags: int, data: str | None) -> None:
    if libc.mount(source.encode(), target.encode(), None if fstype is None else fstype.encode(), flags,
                  None if data is None else data.encode()) != 0:
        err = ctypes.get_errno()
        raise OSError(err, f"mount {source} on {target}: {os.strerror(err)}")


def _under(path: str, folder: str) -> bool:
    return path == folder or path.startswith(folder.rstrip("/") + "/")


def _mount_points() -> list[str]:
    """Every mount point of this mount namespace (``/proc/self/mountinfo``'s fifth field, unescaped)."""
    with open("/proc/self/mountinfo", encoding="utf-8") as handle:
        points = [line.split()[4] for line in handle if line.strip()]
    return [re.sub(r"\\([0-7]{3})", lambda m: chr(int(m.group(1), 8)), p) for p in points]


def _read_only(libc: ctypes.CDLL, scratch: set[str]) -> None:
    """Every mount read-only but the tmpfs ``scratch`` folders and ``/proc``: the policy can
    change no file a later process (a worker, the driver) would read or import."""
    for point in dict.fromkeys(_mount_points()):
        if point in scratch or _under(point, "/proc") or not os.path.exists(point):
            continue
        kept = os.statvfs(point).f_flag & (os.ST_NOSUID | os.ST_NODEV | os.ST_NOEXEC | os.ST_NOATIME | os.ST_NODIRATIME)
        _mount(libc, "none", point, None, MS_REMOUNT | MS_BIND | MS_RDONLY | kept, None)


def seal_here(spec: dict) -> None:
    """In the sandbox's first process (root of its user namespace): cover, bind back, lock (module docstring)."""
    libc = _libc()
    folders = [os.path.realpath(f) for f in (*HIDDEN, spec["home"], *spec["folders"])]
    folders = sorted({f for f in folders if f != "/"}, key=len)
    keep = sorted({k for k in spec["keep"] if os.path.exists(k) and any(_under(k, f) for f in folders)}, key=len)
    held = {k: os.open(k, os.O_PATH) for k in keep}  # reachable after the cover, through /proc/self/fd
    outer = [f for f in folders if os.path.isdir(f) and not any(_under(f, o) and f != o for o in folders)]
    scratch = set(outer)
    for folder in outer:
        _mount(libc, "tmpfs", folder, "tmpfs", MS_NOSUID | MS_NODEV, "mode=1777,size=256m")
    for path, fd in held.items():
        if os.path.isdir(f"/proc/self/fd/{fd}"):
            os.makedirs(path, exist_ok=True)
        else:
            os.makedirs(os.path.dirname(path), exist_ok=True)
            open(path, "a").close()
        _mount(libc, f"/proc/self/fd/{fd}", path, None, MS_BIND | MS_REC, None)
        os.close(fd)
    for folder in folders:  # one inside a folder bound back (the secret's beside the policy's module)
        if folder not in outer and os.path.isdir(folder):
            _mount(libc, "tmpfs", folder, "tmpfs", MS_NOSUID | MS_NODEV, "mode=1777,size=256m")
            scratch.add(folder)
    for path in spec["files"]:
        if os.path.exists(path):
            _mount(libc, "/dev/null", path, None, MS_BIND, None)
    _read_only(libc, scratch)
    if libc.prctl(PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0) != 0 or libc.unshare(CLONE_NEWUSER | CLONE_NEWNS) != 0:
        err = ctypes.get_errno()
        raise OSError(err, f"cannot drop the sandbox's privileges: {os.strerror(err)}")


def configured(seal: Seal, ref: str, config: dict | None) -> dict | None:
    """The configuration of ``ref``'s kind made sealed: for a kind whose configuration loads
    the user's code (an SB3 zip unpickles it), never in the driver, which holds the secret.
    What comes back is the policy's word: at most :data:`MAX_CONFIG_BYTES` of JSON, an object
    or null; PolicyError with its one line otherwise."""
    argv = [sys.executable, "-m", INSIDE, "configure", ref, json.dumps(config)]
    process = subprocess.Popen(_sealed(check_available(), seal, argv), stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, env=environment())
    try:
        out, err = capped_output(process, CONFIGURE_TIMEOUT_S, MAX_CONFIG_BYTES)
    except subprocess.TimeoutExpired:
        raise PolicyError(f"{printable(ref, 60)}: its configuration took more than {CONFIGURE_TIMEOUT_S:.0f} s") from None
    if process.returncode != 0:
        text = err.decode("utf-8", "replace").strip().splitlines()
        raise PolicyError(printable(text[-1], 300) if text else f"{printable(ref, 60)}: exit {process.returncode}")
    try:
        if len(out) > MAX_CONFIG_BYTES:
            raise ValueError(f"more than {MAX_CONFIG_BYTES} bytes")
        lines = out.strip().splitlines()  # the last line: a library may print before it
        made = json.loads(lines[-1] if lines else b"")
        if made is not None and not isinstance(made, dict):
            raise ValueError(type(made).__name__)
    except ValueError as exc:
        raise PolicyError(f"{printable(ref, 60)}: its sealed configuration is not a JSON object ({exc})") from None
    return made


def capped_output(process: subprocess.Popen[bytes], timeout_s: float, cap: int) -> tuple[bytes, bytes]:
    """``process``'s stdout and stderr, each kept to ``cap`` + 1 bytes (the rest read and
    dropped, so a child that prints without end costs no memory), once it exits; killed and
    TimeoutExpired after ``timeout_s``."""
    kept: dict[int, bytearray] = {}
    deadline = time.monotonic() + timeout_s
    with selectors.DefaultSelector() as selector:
        for pipe in (process.stdout, process.stderr):
            if pipe is not None:
                selector.register(pipe, selectors.EVENT_READ)
                kept[pipe.fileno()] = bytearray()
        while selector.get_map():
            left = deadline - time.monotonic()
            if left <= 0:
                process.kill()
                process.wait()
                raise subprocess.TimeoutExpired(process.args, timeout_s)
            for key, _ in selector.select(min(left, 1.0)):
                chunk = os.read(key.fd, 65536)
                if not chunk:
                    selector.unregister(key.fileobj)
                elif len(kept[key.fd]) <= cap:
                    kept[key.fd] += chunk[: cap + 1 - len(kept[key.fd])]
    process.wait(max(0.0, deadline - time.monotonic()))
    out = bytes(kept[process.stdout.fileno()]) if process.stdout is not None else b""
    err = bytes(kept[process.stderr.fileno()]) if process.stderr is not None else b""
    for pipe in (process.stdout, process.stderr):
        if pipe is not None:
            pipe.close()
    return out, err


def main(argv: Sequence[str]) -> int:
    """``SPEC -- COMMAND...``: seal this process, then run COMMAND (:data:`INSIDE`'s)."""
    if len(argv) < 3 or argv[1] != "--":
        print("usage: python -m pipeline.remote.sandbox SPEC -- COMMAND...", file=sys.stderr)
        return 2
    try:
        seal_here(json.loads(argv[0]))
    except OSError as exc:
        print(f"sealed policy: {exc.strerror or exc}", file=sys.stderr, flush=True)
        return 1
    os.execv(argv[2], list(argv[2:]))
    return 1  # not reached


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
