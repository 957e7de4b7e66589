"""Which cameras have a rolling shutter: a small table of common survey-drone cameras by EXIF model.

A rolling shutter exposes the rows one after the other (readout 20-60 ms on the small-sensor drone
cameras); at 5-10 m/s the image is skewed by several centimetres along track, which the global-shutter
camera model cannot absorb. For such cameras the adjustment models the readout (each image row seen from
where the camera was at its exposure, the readout time estimated or given; adjustment/bundle_adjustment.py)
where it adjusts the images with GNSS velocities, and warns where it cannot.
"""

from __future__ import annotations

# EXIF Model -> (rolling shutter?, camera as sold)
KNOWN_CAMERAS: dict[str, tuple[bool, str]] = {
    "FC330": (True, "DJI Phantom 4"),
    "FC6310": (False, "DJI Phantom 4 Pro / Advanced (mechanical shutter)"),
    "FC6310S": (False, "DJI Phantom 4 Pro V2 (mechanical shutter)"),
    "FC6310R": (False, "DJI Phantom 4 RTK (mechanical shutter)"),
    "FC220": (True, "DJI Mavic Pro"),
    "FC2103": (True, "DJI Mavic Air"),
    "FC3170": (True, "DJI Mavic Air 2"),
    "FC3411": (True, "DJI Air 2S"),
    "L1D-20C": (True, "DJI Mavic 2 Pro (Hasselblad L1D-20c)"),
    "FC2220": (True, "DJI Mavic 2 Enterprise"),
    "FC7203": (True, "DJI Mavic Mini"),
    "FC7303": (True, "DJI Mini 2"),
    "FC3582": (True, "DJI Mini 3 Pro"),
    "M3E": (False, "DJI Mavic 3 Enterprise (mechanical shutter)"),
    "ZENMUSEP1": (False, "DJI Zenmuse P1 (global/mechanical shutter)"),
    "FC6520": (True, "DJI Zenmuse X5S"),
    "FC6540": (True, "DJI Zenmuse X7"),
    "SIMCAM-RS": (True, "Georef's simulated rolling-shutter camera (georef simulate --readout-ms)"),
}


def rolling_shutter_of(model: str | None) -> tuple[bool | None, str]:
    """(rolling?, description) for an EXIF camera model; (None, ...) when the model is not in the table."""
    if not model:
        return None, "no camera model in EXIF"
    key = model.strip().upper().replace(" ", "")
    if key in KNOWN_CAMERAS:
        rolling, name = KNOWN_CAMERAS[key]
        return rolling, name
    return None, f"camera model {model.strip()!r} is not in Georef's shutter table"
