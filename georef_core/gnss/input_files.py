"""Recognise a GNSS input file by its content (RINEX observation, RINEX navigation, u-blox UBX) and load it."""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import InputFileError
from .compressed_files import is_hatanaka, read_bytes
from .navigation import NavigationData
from .observations import RawObservations

UBX_SYNC = b"\xb5\x62"


def sniff_kind(path) -> str:
    """'rinex-obs', 'rinex-nav', 'ubx' or 'unknown' from the first bytes of the (decompressed) file."""
    data = read_bytes(path)[:65536]
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
    if UBX_SYNC in data[:4096]:
        return "ubx"
    return "unknown"


@dataclass
class LoadedObservations:
    observations: RawObservations
    navigation: NavigationData | None   # UBX logs carry their own navigation messages
    kind: str


def load_observations(path) -> LoadedObservations:
    kind = sniff_kind(path)
    if kind == "rinex-obs":
        from .rinex_obs import read_rinex_obs

        return LoadedObservations(read_rinex_obs(path), None, kind)
    if kind == "ubx":
        from .ubx import read_ubx

        log = read_ubx(path)
        raw = log.observations
        if len(log.event_gps_time_s) and not len(raw.event_gps_time_s):
            raw.event_gps_time_s = log.event_gps_time_s
        return LoadedObservations(raw, log.navigation, kind)
    if kind == "rinex-nav":
        raise InputFileError(path, "this is a RINEX navigation file; an observation file (RINEX obs or UBX) was expected here")
    raise InputFileError(path, "not a RINEX observation file nor a u-blox UBX log")


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
        elif kind == "rinex-obs":
            raise InputFileError(p, "this is a RINEX observation file; a navigation file was expected here")
        else:
            raise InputFileError(p, "not a RINEX navigation file nor a u-blox UBX log")
    return nav
