"""Cross-check of the two records a DJI RTK aircraft keeps of its real-time solution at each exposure: the
``Timestamp.MRK`` line (quality flag ``Q``, sigmas north / east / vertical) and the photo's XMP (``RtkFlag``,
``RtkStdLat`` / ``RtkStdLon`` / ``RtkStdHgt``).

Both are written by the aircraft from the same solution at the same exposure, so they should agree to their
printing precision. A disagreement means that the photo and the MRK line do not belong together (photos renamed,
an MRK of another flight, a photo whose XMP was edited or re-exported by other software) or that the firmware
wrote one of them at another instant; either way the weight or the fixed/float grouping that Georef takes from
the photo (photos alone) or would take from the MRK is in doubt, so each disagreeing exposure is named.

The rule (docs/dji.md, "MRK against XMP"):

* quality: the two codes' classes differ (50 fixed; 32-49 float, DJI's range for float; 1-31 single point or
  differential; 0 no position; any other code is its own class);
* sigmas: on any axis the larger of the two, over the smaller, exceeds ``SIGMA_RATIO_TOLERANCE`` (1.25: a weight
  changed by more than 56 %), both taken at least at the 5 mm floor the adjustment applies to RTK sigmas (below it
  the weight does not change). Only where both records state the sigma.

An exposure whose MRK has no quality/sigma columns, or whose photo has no ``RtkFlag``, is counted as not checked.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..errors import InputFileError
from .dji_xmp import read_dji_xmp
from .photo_positions import RTK_SIGMA_FLOOR_M

SIGMA_RATIO_TOLERANCE = 1.25
MAX_LISTED = 20          # disagreements listed one by one in the summary (all are counted)


def rtk_quality_class(code: int | None) -> str | None:
    """The class of a DJI RTK quality code (MRK ``Q``, XMP ``RtkFlag``); None for a missing code."""
    if code is None or code < 0:
        return None
    if code == 50:
        return "fixed"
    if 32 <= code <= 49:
        return "float"
    if 1 <= code <= 31:
        return "single"
    if code == 0:
        return "none"
    return f"code {code}"


def _sigma_mismatch(mrk_neu_m, xmp_neu_m) -> list[str]:
    out = []
    for axis, a, b in zip(("north", "east", "up"), mrk_neu_m, xmp_neu_m):
        if a is None or b is None or not (math.isfinite(a) and math.isfinite(b)):
            continue
        lo, hi = sorted((max(float(a), RTK_SIGMA_FLOOR_M), max(float(b), RTK_SIGMA_FLOOR_M)))
        if hi / lo > SIGMA_RATIO_TOLERANCE:
            out.append(f"sigma {axis} {float(a):.4f} m (MRK) vs {float(b):.4f} m (XMP)")
    return out


def cross_check_mrk_xmp(exposures) -> dict:
    """``exposures``: (image name, photo path, MRK quality code (-1 absent), MRK sigma north/east/vertical in m
    (NaN absent)) per photo, paired as survey_inputs pairs photos and MRK rows. Returns counts, the rule and the
    disagreements (image, both codes and sigmas, why), the first MAX_LISTED listed, all named in ``images``."""
    checked, not_checked, unreadable = 0, [], []
    bad = []
    for name, photo, mrk_q, mrk_sig in exposures:
        try:
            x = read_dji_xmp(Path(photo))
        except InputFileError as exc:
            unreadable.append(f"{name}: {exc}")
            continue
        mrk_class = rtk_quality_class(int(mrk_q))
        mrk_sig = [float(v) for v in np.asarray(mrk_sig, float).reshape(3)]
        xmp_sig = [None] * 3 if x is None else [x.rtk_std_lat_m, x.rtk_std_lon_m, x.rtk_std_hgt_m]
        xmp_flag = None if x is None or x.rtk_flag is None else int(x.rtk_flag)
        if mrk_class is None or xmp_flag is None:
            not_checked.append(name)
            continue
        checked += 1
        why = []
        if rtk_quality_class(xmp_flag) != mrk_class:
            why.append(f"quality {int(mrk_q)} ({mrk_class}, MRK) vs RtkFlag {xmp_flag} ({rtk_quality_class(xmp_flag)}, "
                       "XMP)")
        why += _sigma_mismatch(mrk_sig, xmp_sig)
        if why:
            bad.append({"image": name, "mrk_quality": int(mrk_q), "xmp_rtk_flag": xmp_flag,
                        "mrk_sigma_neu_m": [None if not math.isfinite(v) else round(v, 5) for v in mrk_sig],
                        "xmp_sigma_neu_m": [None if v is None else round(float(v), 5) for v in xmp_sig],
                        "why": why})
    return {"checked": checked, "agree": checked - len(bad), "disagree": len(bad),
            "not_checked": len(not_checked), "unreadable_xmp": unreadable,
            "images": [b["image"] for b in bad], "disagreements": bad[:MAX_LISTED],
            "rule": f"quality classes (50 fixed, 32-49 float, 1-31 single, 0 none) must be equal; each sigma within a "
                    f"factor {SIGMA_RATIO_TOLERANCE:g} (both floored at {1000 * RTK_SIGMA_FLOOR_M:g} mm)"}


def cross_check_warning(result: dict, used: str) -> str | None:
    """The warning for a cross-check with disagreements (None without): how many, which photos, and which
    record the processing uses (``used``)."""
    n = result.get("disagree", 0)
    if not n:
        return None
    names = result["images"]
    kinds = sorted({w.split(" ")[0] for b in result["disagreements"] for w in b["why"]})
    return (f"the MRK and the photos' XMP disagree on the RTK {' and '.join(kinds)} of {n} of {result['checked']} "
            f"exposure(s) ({', '.join(names[:10])}{' ...' if len(names) > 10 else ''}): the aircraft writes both from "
            f"one solution, so these photos and MRK lines may not belong together, or a photo's XMP was edited; "
            f"{used} (georef_summary.json -> inputs.rtk_cross_check)")
