"""Text of the survey report: escaping (every piece of user or processing text enters a ReportLab Paragraph
as escaped text, never as markup: docs/security.md), paths reduced to file names, figures with their units,
and the sentences that say in words what the georeferencing estimated (lever arm, trigger delay)."""

from __future__ import annotations

import math
import re
from pathlib import Path
from xml.sax.saxutils import escape

# characters XML 1.0 does not allow (the Paragraph parser is XML-like): replaced, not passed through
BAD_CHARS = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f\ufffe\uffff]")
# an absolute POSIX path (two components at least) or a Windows drive path, not part of a URL or a ratio
ABS_PATH = re.compile(r"(?<![\w.:/~-])(?:/|[A-Za-z]:\\)(?:[^\s/\\'\"<>|:;,()]+[/\\])+([^\s/\\'\"<>|:;,()]*)")


def esc(value) -> str:
    """Plain text -> Paragraph markup that shows exactly that text."""
    return escape(BAD_CHARS.sub("?", "" if value is None else str(value)))


def plain(value) -> str:
    """Text for a table cell or a drawing (not parsed as markup): only the characters XML refuses replaced."""
    return BAD_CHARS.sub("?", "" if value is None else str(value))


def scrub(value, run_dir: Path | None = None) -> str:
    """Text from the processing with file paths reduced to file names (relative to the run folder where
    they are inside it)."""
    text = "" if value is None else str(value)
    if run_dir is not None:
        run_dir = Path(run_dir)
        # the worker passes its run folder's out/ (beside survey/): both, then the folder itself
        for base in (run_dir.parent / "survey", run_dir.parent / "out", run_dir / "survey", run_dir / "out", run_dir):
            text = text.replace(str(base) + "/", "")
    return ABS_PATH.sub(lambda m: m.group(1) or "", text)


def finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def fmt(v, nd=3, unit="") -> str:
    """A number with nd decimals and its unit; '-' for none."""
    if not finite(v):
        return "-"
    return f"{round(v, nd) + 0.0:.{nd}f}{unit}"      # + 0.0: no "-0.000"


def cm(v_m, nd=1) -> str:
    """Metres shown in centimetres: '1.2 cm'."""
    return fmt(None if not finite(v_m) else 100.0 * v_m, nd, " cm")


def pm_cm(v_m, sigma_m, nd=1) -> str:
    """'12.3 cm ± 0.4 cm' (the value's magnitude; the sign is said in words)."""
    s = f"{100.0 * abs(v_m):.{nd}f} cm"
    return s + (f" ± {100.0 * sigma_m:.{nd}f} cm" if finite(sigma_m) else "")


# the camera frame of the lever arm (docs/georeferencing.md): x right in the image, y down, z along the view
_LEVER_WORDS = (("to the right", "to the left"), ("towards the bottom of the image", "towards the top of the image"),
                ("along the viewing direction", "against the viewing direction"))


def lever_arm_sentence(lever_m, sigma_m=None, estimated: bool | None = None) -> str:
    """The lever arm in words: where the camera's projection centre sits seen from the antenna's phase
    centre, each component with its 1-sigma, in the camera's axes."""
    if not (isinstance(lever_m, (list, tuple)) and len(lever_m) == 3 and all(finite(v) for v in lever_m)):
        return "The lever arm is not known for this run."
    sig = list(sigma_m) if isinstance(sigma_m, (list, tuple)) and len(sigma_m) == 3 else [None] * 3
    parts = [f"{pm_cm(v, s)} {_LEVER_WORDS[k][0 if v >= 0 else 1]}" for k, (v, s) in enumerate(zip(lever_m, sig))]
    how = ("estimated in the adjustment (± one standard deviation)" if estimated or any(finite(s) for s in sig)
           else "held at the given value (not estimated)")
    return (f"Seen from the GNSS antenna's phase centre, the camera's projection centre sits {parts[0]}, {parts[1]} "
            f"and {parts[2]}; {how}. The directions are the camera's: right and bottom as in the photos; the viewing "
            "direction points down for a camera looking straight down; on an aircraft whose image top faces its "
            "nose, the top of the image is forward.")


def delay_sentence(delay_s, sigma_s=None) -> str:
    if not finite(delay_s):
        return "The trigger delay is not known for this run."
    when = "after" if delay_s >= 0 else "before"
    ms = f"{abs(delay_s) * 1000:.1f} ms"
    if finite(sigma_s):
        return (f"The camera exposes {ms} ± {sigma_s * 1000:.1f} ms {when} the trigger time the GNSS receiver "
                "recorded (estimated in the adjustment, ± one standard deviation).")
    return f"The camera exposes {ms} {when} the recorded trigger time: held at this value (not estimated)."
