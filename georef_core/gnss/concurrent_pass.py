"""The second filter pass of a solve (the witness of a forward or backward run, or the other half of a
combined one) run in a forked child on another core while this process runs the first pass.

The two passes are independent (unless a known start makes the second start where the first ended: then
they run one after the other), compiled code over the same read-only arrays, so the child computes what
this process would have computed: its result comes back pickled through a pipe, the same arrays bit for
bit (tests/gnss/test_concurrent_pass.py compares the .pos of both ways). Whenever anything of this fails
(no fork, a child that dies or says nothing, a short read) the pass is simply run here, serially, and the
result is the same.

Used only where it can pay (`worth_forking`): at least two CPUs this process may run on
(os.sched_getaffinity), one of them idle (the 1-minute load average), one Python thread (forking a process
whose other threads hold locks is unsafe), and a pass big enough that a fork (~1 ms from a 300 MB process,
~1 ms to read the result back, and the copies of the pages parent and child then write: ~10 us each on the
2-core virtual machine, ~3 000-5 000 of them per solve) is a small part of it.
GEOREF_GNSS_CONCURRENT_PASSES=0 turns it off (every pass serial, as before), =1 forces it whenever a fork
is possible, other threads or not (the tests use it on a small file, in pytest-xdist workers). docs/gnss.md, "Speed".
"""

from __future__ import annotations

import gc
import os
import pickle
import signal
import struct
import threading

# signal-epochs (epochs x satellites x bands of the prepared arrays) from which a pass is worth a fork: a
# GEONET 120-epoch L1 pass (~1.7 ms, ~1 400 signal-epochs) is not, the u-blox walk's (~50 ms, ~40 000) is
MIN_SIGNAL_EPOCHS = 6000
# ... and only while a CPU is idle: the 1-minute load average at most (usable CPUs - MIN_IDLE_CPUS). On the
# shared 2-core machine at load 3.5-4.5 the forked pass cost more than it saved in a served solve (the u-blox
# walk forward: median 0.41 -> 0.52 s; the child's pass ~1.7x its serial time and ~5 000 more page faults
# in the parent, copies of the pages the two now share): no core to spare, no fork
MIN_IDLE_CPUS = 1
ENV = "GEOREF_GNSS_CONCURRENT_PASSES"
_HEADER = struct.Struct("<Q")
PR_SET_PDEATHSIG = 1


def usable_cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def worth_forking(signal_epochs: int) -> bool:
    """Whether the second pass of a solve of this size runs in a forked child (module docstring)."""
    setting = os.environ.get(ENV, "").strip().lower()
    if setting in ("0", "off", "no", "false"):
        return False
    if not hasattr(os, "fork"):
        return False
    if setting in ("1", "on", "yes", "true", "always"):   # forced (the tests; pytest-xdist's workers run threads)
        return True
    if threading.active_count() != 1:
        return False
    cpus = usable_cpus()
    return cpus >= 2 and signal_epochs >= MIN_SIGNAL_EPOCHS and _load_1min() <= cpus - MIN_IDLE_CPUS


def _load_1min() -> float:
    try:
        return os.getloadavg()[0]
    except (AttributeError, OSError):
        return 0.0


def _die_with_parent(parent_pid: int) -> None:
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent_pid:
        os._exit(1)


def _write_all(fd: int, data) -> None:
    view = memoryview(data)
    while view:
        n = os.write(fd, view)
        view = view[n:]


def _read_exactly(fd: int, n: int) -> bytes | None:
    chunks, got = [], 0
    while got < n:
        chunk = os.read(fd, min(n - got, 1 << 20))
        if not chunk:
            return None
        chunks.append(chunk)
        got += len(chunk)
    return b"".join(chunks)


class ForkedPass:
    """``fn()`` (no argument, returning picklable arrays) started in a forked child; ``result()`` returns
    its value, computed here instead when the child could not give it. ``cancel()`` ends the child
    (KeyboardInterrupt or an error in the first pass). Use only where worth_forking() said so."""

    def __init__(self, fn):
        self.fn = fn
        self.pid = None
        self.fd = -1
        parent = os.getpid()
        try:
            r, w = os.pipe()
        except OSError:
            return
        try:
            pid = os.fork()
        except OSError:
            os.close(r)
            os.close(w)
            return
        if pid == 0:   # the child: compute, send, exit without running any of the parent's exit code
            code = 1
            try:
                signal.signal(signal.SIGINT, signal.SIG_IGN)   # Ctrl-C is the parent's: it cancels us
                gc.disable()   # a short life: no collection touching (copying) the parent's pages
                os.close(r)
                _die_with_parent(parent)
                payload = pickle.dumps(fn(), protocol=pickle.HIGHEST_PROTOCOL)
                _write_all(w, _HEADER.pack(len(payload)))
                _write_all(w, payload)
                code = 0
            except BaseException:   # noqa: BLE001 - the parent runs the pass itself
                code = 1
            finally:
                os._exit(code)
        os.close(w)
        self.pid, self.fd = pid, r

    def _reap(self) -> int | None:
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1
        pid, self.pid = self.pid, None
        if pid is None:
            return None
        try:
            return os.waitpid(pid, 0)[1]
        except ChildProcessError:
            return None

    def result(self):
        value = None
        try:
            if self.fd >= 0:
                head = _read_exactly(self.fd, _HEADER.size)
                data = _read_exactly(self.fd, _HEADER.unpack(head)[0]) if head is not None else None
                if data is not None:
                    value = pickle.loads(data)
        except (OSError, pickle.UnpicklingError, EOFError, ValueError):
            value = None
        finally:
            status = self._reap()
        if value is None or status is None or os.waitstatus_to_exitcode(status) != 0:
            return self.fn()   # the child did not give it: the same pass, here
        return value

    def cancel(self) -> None:
        if self.pid is not None:
            try:
                os.kill(self.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        self._reap()
