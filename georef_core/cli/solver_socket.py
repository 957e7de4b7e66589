"""Where the resident GNSS solver listens, and who may talk to it: the per-user run folder, the digest that
names the socket, and the message framing shared by the client (solver_client.py) and the server
(solver_server.py). Standard library only: the client imports this before anything heavy (docs/gnss.md,
"The resident solver").

The socket's name is a digest of everything the server fixed when it started and a solve's result depends
on: the identity (size, modification time in ns, inode) of every georef_core source file and of the
ahead-of-time kernel module and its description (the rule Python's own bytecode cache uses to see an edited
source, plus the inode: an editor or pip that replaces a file changes it; reading the 2.4 MB of sources
cost a client 10-35 ms on the loaded machine, the stat calls ~1-2 ms), the interpreter, the identity (path, mtime) of every folder on the import path but the script's own (a package
installed or upgraded changes its folder's mtime) and the environment variables read at import time
(GEOREF_GNSS_AOT, NUMBA_*, the BLAS thread counts, PYTHONPATH, PYTHONHASHSEED). A client whose tree
differs computes another name and never reaches a stale server.
"""

from __future__ import annotations

import json
import os
import stat
import struct
import sys
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parents[1]   # georef_core/
ENV_SWITCH = "GEOREF_GNSS_SERVER"     # 0/off: never; manual: only a server started by `georef gnss server start`
ENV_RUN_DIR = "GEOREF_RUN_DIR"        # the run folder (default $XDG_RUNTIME_DIR/georef or ~/.cache/georef/run)
# read when the server imports numpy, numba and the kernels: a different value needs another server
IMPORT_TIME_ENV = ("GEOREF_GNSS_AOT", "PYTHONPATH", "PYTHONHASHSEED", "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS",
                   "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS")
SOCKET_PATH_MAX = 107                 # sun_path is 108 bytes, NUL included
PROTOCOL = 1


class RunDirError(Exception):
    """The run folder cannot be used safely (not ours, open to others, a symbolic link)."""


def run_dir(create: bool = True) -> Path:
    """The per-user folder of the server's socket, lock and log: created 0700; refused (RunDirError) when
    it is a symbolic link, not owned by this user, or readable/writable by group or others."""
    explicit = os.environ.get(ENV_RUN_DIR)
    if explicit:
        path = Path(explicit)
    elif os.environ.get("XDG_RUNTIME_DIR"):
        path = Path(os.environ["XDG_RUNTIME_DIR"]) / "georef"
    else:
        path = Path.home() / ".cache" / "georef" / "run"
    if create:
        path.parent.mkdir(parents=True, exist_ok=True)
        try:
            path.mkdir(mode=0o700)
        except FileExistsError:
            pass
    check_run_dir(path)
    return path


def check_run_dir(path: Path) -> None:
    try:
        st = os.lstat(path)
    except OSError as exc:
        raise RunDirError(f"{path}: {exc.strerror}") from None
    if stat.S_ISLNK(st.st_mode) or not stat.S_ISDIR(st.st_mode):
        raise RunDirError(f"{path}: not a folder (a symbolic link or a file); the resident solver is not used")
    if st.st_uid != os.getuid():
        raise RunDirError(f"{path}: owned by uid {st.st_uid}, not by you (uid {os.getuid()}); the resident solver "
                          "is not used")
    if st.st_mode & 0o077:
        raise RunDirError(f"{path}: open to other users (mode {stat.S_IMODE(st.st_mode):o}, 700 expected); the "
                          "resident solver is not used")


def _sha256():
    """hashlib's SHA-256 without loading OpenSSL (~6 ms of a client's start): CPython's own module."""
    for name in ("_sha256", "_sha2"):
        try:
            return __import__(name).sha256()
        except (ImportError, AttributeError):
            continue
    import hashlib

    return hashlib.sha256()


def source_digest() -> str:
    """SHA-256 (hex) of what the server fixed at its start (module doc): ~1-2 ms (stat calls, no reading)."""
    h = _sha256()
    h.update(f"protocol {PROTOCOL}\n{sys.executable}\n{sys.version}\n{PACKAGE_DIR}\n".encode())
    for key in IMPORT_TIME_ENV:
        h.update(f"{key}={os.environ.get(key)}\n".encode())
    for key in sorted(k for k in os.environ if k.startswith("NUMBA_")):
        h.update(f"{key}={os.environ[key]}\n".encode())
    for entry in sys.path[1:]:   # [0] is the script's folder: the server's differs, and is not where packages are
        try:
            h.update(f"path {entry} {os.stat(entry or '.').st_mtime_ns}\n".encode())
        except OSError:
            h.update(f"path {entry} -\n".encode())
    for root, dirs, files in os.walk(PACKAGE_DIR):
        dirs[:] = sorted(d for d in dirs if d != "__pycache__")
        rel_root = os.path.relpath(root, PACKAGE_DIR)
        for name in sorted(files):
            if name.endswith(".py") or name.startswith("_gnss_kernels_aot."):
                st = os.stat(os.path.join(root, name))
                h.update(f"{rel_root}/{name} {st.st_size} {st.st_mtime_ns} {st.st_ino}\n".encode())
    return h.hexdigest()


def socket_path(folder: Path, digest: str) -> Path:
    return folder / f"gnss-{digest[:24]}.sock"


def unix_address(path: Path, call) -> None:
    """``call(address)`` (a socket's bind or connect) with ``path``, or, where the path is longer than an AF_UNIX
    address holds (SOCKET_PATH_MAX: a deep temporary or home folder), with its name while the working folder is
    the socket's folder (restored after, also on error)."""
    if len(os.fsencode(path)) <= SOCKET_PATH_MAX:
        call(os.fspath(path))
        return
    here = os.open(".", os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    try:
        os.chdir(path.parent)
        call(path.name)
    finally:
        os.fchdir(here)
        os.close(here)


def lock_path(folder: Path, digest: str) -> Path:
    return folder / f"gnss-{digest[:24]}.lock"


def failed_path(folder: Path, digest: str) -> Path:
    """Written by a server that could not load the solver: no automatic start for that installation."""
    return folder / f"gnss-{digest[:24]}.failed"


def log_path(folder: Path, digest: str) -> Path:
    return folder / f"gnss-{digest[:24]}.log"


# ------------------------------------------------------------------------------------------ framing
# client -> server: one request, a 4-byte length then JSON (the solve's three standard streams ride along as
# SCM_RIGHTS); then single bytes: b"I" (forward SIGINT), b"T" (SIGTERM). server -> client: JSON lines.

def pack_request(request: dict) -> bytes:
    body = json.dumps(request).encode()
    return struct.pack("!I", len(body)) + body


def request_length(head: bytes) -> int:
    return struct.unpack("!I", head[:4])[0]


def read_line(sock, buffer: bytearray) -> dict | None:
    """The next JSON line from the socket (None at end of stream)."""
    while b"\n" not in buffer:
        chunk = sock.recv(4096)
        if not chunk:
            return None
        buffer += chunk
    line, _, rest = bytes(buffer).partition(b"\n")
    buffer[:] = rest
    return json.loads(line)
