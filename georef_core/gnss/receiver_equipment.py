"""Which receiver and antenna recorded a GNSS observation file, as the file says it: the RINEX header's
``REC # / TYPE / VERS`` and ``ANT # / TYPE`` records, an RTCM 3 stream's receiver and antenna descriptors
(messages 1033, 1007/1008), a u-blox log's MON-VER message. A file that names neither (a UBX log without
MON-VER, a DJI aircraft's RTCM 3 raw log without 1033) is described by its format: "u-blox (UBX)", "DJI
RTCM 3 log". The PPK step keeps this in its summary ("equipment") and the survey report prints it."""

from __future__ import annotations

from pathlib import Path

# what the readers put in ReceiverHeader.receiver_type when the file names no receiver
_NO_RECEIVER = {"u-blox", "rtcm 3 stream", "unknown", "none", "-", ""}
FORMAT_LABELS = {"ubx": "u-blox (UBX)", "rtcm3": "RTCM 3 log", "dji-rtcm3": "DJI RTCM 3 log"}


def _clean(text) -> str | None:
    text = " ".join(str(text or "").split())
    return None if text.lower() in _NO_RECEIVER else text


def split_antenna(descriptor: str) -> tuple[str | None, str | None]:
    """(model, radome) of an IGS antenna descriptor: the model in its first 16 characters, the radome code in
    the next 4 ("NONE": none fitted). A descriptor that does not follow that layout is all model."""
    d = str(descriptor or "").rstrip()
    if len(d) > 16 and d[16:20].strip() and not d[15].strip():
        model, radome = d[:16].strip(), d[16:20].strip()
    else:
        model, radome = d.strip(), None
    return _clean(model), (radome or None)


def receiver_equipment(info, kind: str, files=(), dji: bool = False) -> dict:
    """The receiver and antenna of one receiver's observations. ``info``: the reader's ReceiverHeader;
    ``kind``: input_files.sniff_kind of its (first) file; ``dji``: a DJI aircraft's raw log. Returns
    {"receiver", "receiver_version", "antenna", "radome" (None where the file does not say), "format" (e.g.
    "RINEX 3.04", "u-blox (UBX)", "DJI RTCM 3 log"), "source" (the records they were read from), "files"
    (names)}."""
    receiver = _clean(getattr(info, "receiver_type", ""))
    version = _clean(getattr(info, "receiver_version", ""))
    antenna, radome = split_antenna(getattr(info, "antenna_type", ""))
    if kind == "rinex-obs":
        v = getattr(info, "rinex_version", None)
        fmt = f"RINEX {v:.2f}" if v else "RINEX"
        source = "RINEX header (REC # / TYPE / VERS, ANT # / TYPE)"
    elif kind == "rtcm3":
        fmt = FORMAT_LABELS["dji-rtcm3" if dji else "rtcm3"]
        source = "RTCM 3 receiver/antenna descriptor messages (1033, 1007/1008)"
    elif kind == "ubx":
        fmt = FORMAT_LABELS["ubx"]
        source = "UBX MON-VER message"
    else:
        fmt, source = kind, ""
    if receiver is None and antenna is None:
        source = "not stated in the file"
    return {"receiver": receiver, "receiver_version": version if receiver else None, "antenna": antenna,
            "radome": radome if antenna else None, "format": fmt, "source": source,
            "files": [Path(str(f)).name for f in files]}


def equipment_of_loaded(loaded, paths, dji: bool = False) -> dict:
    """:func:`receiver_equipment` of what input_files.load_observations (or ppk.load_receiver) returned for
    ``paths`` (one path or a list: the first file's format)."""
    from .input_files import sniff_kind

    paths = [paths] if isinstance(paths, (str, Path)) else list(paths)
    kind = loaded.kind if loaded.kind != "joined" else (sniff_kind(paths[0]) if paths else "")
    return receiver_equipment(loaded.observations.header, kind, paths, dji)


def equipment_text(eq: dict | None) -> str:
    """One line for a report: "TRIMBLE NetR9 (version 5.37), antenna TRM159900.00, radome SCIS; from the
    RINEX 3.04 header", or the format alone when the file names no equipment."""
    if not eq:
        return "not recorded"
    parts = []
    if eq.get("receiver"):
        parts.append(eq["receiver"] + (f" (version {eq['receiver_version']})" if eq.get("receiver_version") else ""))
    else:
        parts.append("receiver model not stated")
    if eq.get("antenna"):
        rad = eq.get("radome")
        parts.append(f"antenna {eq['antenna']}" + (", no radome" if rad == "NONE" else f", radome {rad}" if rad else ""))
    else:
        parts.append("antenna model not stated")
    fmt = eq.get("format") or "the file"
    if eq.get("receiver") is None and eq.get("antenna") is None:
        return f"{fmt}: {parts[0]}, {parts[1]} in the file"
    where = "header" if fmt.startswith("RINEX") else "log"
    return f"{', '.join(parts)}; from the {fmt} {where}"
