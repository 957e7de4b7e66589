"""Recognise a GNSS input file by its content (RINEX observation, RINEX navigation, u-blox UBX, RTCM 3,
DJI Timestamp.MRK), never by its name, and load it."""

from __future__ import annotations

import contextlib
import contextvars
import os
import warnings
from dataclasses import dataclass

from ..errors import InputFileError
from .compressed_files import is_hatanaka, read_head_bytes
from .navigation import NavigationData
from .observations import RawObservations

GNSS_KINDS = ("rinex-obs", "rinex-nav", "ubx", "rtcm3", "dji-mrk")


def sniff_kind(path) -> str:
    """'rinex-obs', 'rinex-nav', 'ubx', 'rtcm3', 'dji-mrk' or 'unknown' from the first 64 kB of the
    (decompressed) file."""
    return sniff_bytes(read_head_bytes(path, 65536))


def sniff_bytes(data: bytes) -> str:
    """``sniff_kind`` of the first bytes of a file (decompressed). Binary logs are told apart by which
    framing (UBX checksums or RTCM 3 CRC-24Q) covers more of the bytes: a chance ``B5 62`` or ``D3``
    inside the other format's frames does not decide it."""
    if is_hatanaka(data):
        return "rinex-obs"
    head = data[:4000].decode("latin-1", errors="replace")
    first = head.splitlines()[0] if head else ""
    if "RINEX VERSION" in first:
        kind = first[20:21].upper()
        if kind == "O" or "OBSERVATION" in first.upper():
            return "rinex-obs"
        if kind in ("N", "G", "H", "L", "C", "E") or "NAV" in first.upper():
            return "rinex-nav"
        return "unknown"
    from .dji_mrk import looks_like_mrk

    if looks_like_mrk(data[:4096]):
        return "dji-mrk"
    return _binary_log_kind(data)


def _binary_log_kind(data: bytes) -> str:
    from .rtcm3 import find_rtcm3_frames
    from .ubx import find_ubx_frames

    ubx = find_ubx_frames(data)
    rtcm = find_rtcm3_frames(data)
    ubx_bytes = ubx.n_bytes_in_frames if len(ubx.start) else 0
    rtcm_bytes = rtcm.n_bytes_in_frames if len(rtcm.start) >= 2 else 0
    if rtcm_bytes > ubx_bytes:
        return "rtcm3"
    if ubx_bytes > 0:
        return "ubx"
    return "unknown"


@dataclass
class LoadedObservations:
    observations: RawObservations
    navigation: NavigationData | None   # UBX logs carry their own navigation messages
    kind: str


_LOADED: contextvars.ContextVar[dict | None] = contextvars.ContextVar("georef_loaded_observations", default=None)


@contextlib.contextmanager
def reuse_loaded_observations():
    """Within the block, a file loaded twice with the same arguments (and unchanged on disk) is decoded once:
    a step that inspects a raw log before solving it does not pay for the decoding twice. Nothing is kept
    after the block. Callers must not modify what load_observations returns."""
    token = _LOADED.set({})
    try:
        yield
    finally:
        _LOADED.reset(token)


def load_observations(path, approx_gps_time_s: float | None = None, event_edge: str = "falling") -> LoadedObservations:
    """One receiver's observation file. ``approx_gps_time_s`` dates an RTCM 3 stream that carries no
    week number (no ephemeris messages), e.g. a base stream dated by the rover's log. ``event_edge``: the
    TIM-TM2 edge of a UBX log that marks the exposure (ubx.read_ubx)."""
    memo = _LOADED.get()
    if memo is None:
        return _load_observations(path, approx_gps_time_s, event_edge)
    st = os.stat(path)
    key = (os.path.realpath(path), st.st_size, st.st_mtime_ns, approx_gps_time_s, event_edge)
    if key not in memo:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            memo[key] = (_load_observations(path, approx_gps_time_s, event_edge), caught)
    loaded, caught = memo[key]
    for w in caught:   # what the reader said about the file is said to every caller, not only the first
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return loaded


def _load_observations(path, approx_gps_time_s: float | None, event_edge: str) -> LoadedObservations:
    kind = sniff_kind(path)
    if kind == "rinex-obs":
        from .rinex_obs import read_rinex_obs

        return LoadedObservations(read_rinex_obs(path), None, kind)
    if kind == "ubx":
        from .ubx import read_ubx

        log = read_ubx(path, event_edge=event_edge)
        raw = log.observations
        if len(log.event_gps_time_s) and not len(raw.event_gps_time_s):
            raw.event_gps_time_s = log.event_gps_time_s
        return LoadedObservations(raw, log.navigation, kind)
    if kind == "rtcm3":
        from .rtcm3 import read_rtcm3

        rlog = read_rtcm3(path, approx_gps_time_s=approx_gps_time_s)
        if rlog.observations.n_epochs == 0:
            raise InputFileError(path, "this RTCM 3 stream holds no observation (MSM) messages: "
                                       f"messages {', '.join(str(k) for k in rlog.message_counts)}")
        return LoadedObservations(rlog.observations, rlog.navigation, kind)
    if kind == "dji-mrk":
        raise InputFileError(path, "this is a DJI Timestamp.MRK (camera exposures); an observation file "
                                   "(RINEX obs, UBX or RTCM 3 raw log) was expected here")
    if kind == "rinex-nav":
        raise InputFileError(path, "this is a RINEX navigation file; an observation file (RINEX obs or UBX) was expected here")
    raise InputFileError(path, "not a RINEX observation file, a u-blox UBX log nor an RTCM 3 stream")


def load_navigation(paths, time_window_gps_s: tuple[float, float] | None = None) -> NavigationData:
    """Navigation files (RINEX, any packing, or UBX) merged; with a time window (first and last
    observation time), RINEX records far outside it are not read (rinex_nav.read_rinex_nav)."""
    from .rinex_nav import read_rinex_nav

    nav = NavigationData()
    for p in paths:
        kind = sniff_kind(p)
        if kind == "rinex-nav":
            nav = nav.merge(read_rinex_nav(p, time_window_gps_s))
        elif kind == "ubx":
            from .ubx import read_ubx

            nav = nav.merge(read_ubx(p).navigation)
        elif kind == "rtcm3":
            from .rtcm3 import read_rtcm3

            nav = nav.merge(read_rtcm3(p, approx_gps_time_s=None if time_window_gps_s is None
                                       else time_window_gps_s[0]).navigation)
        elif kind == "rinex-obs":
            raise InputFileError(p, "this is a RINEX observation file; a navigation file was expected here")
        else:
            raise InputFileError(p, "not a RINEX navigation file, a u-blox UBX log nor an RTCM 3 stream")
    return nav
