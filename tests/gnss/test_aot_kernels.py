"""The GNSS kernels compiled ahead of time (georef_core/gnss/aot_build.py, kernel_loader.py): a `georef gnss
solve` process that uses them imports no numba and writes the same .pos as numba's kernels; arguments the
compiled variants were not built for, a stale or a missing module, all fall back to numba."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from georef_core.gnss import kernel_loader

DATA = Path(__file__).resolve().parents[1] / "data" / "gnss" / "gsi_0759_3040"
ROVER, BASE, NAV = DATA / "07590920.05o", DATA / "30400920.05o", DATA / "07590920.05n"
REPO = Path(__file__).resolve().parents[2]

# a fresh process solving the GEONET sample with the ahead-of-time kernels requested (GEOREF_GNSS_AOT=1);
# argv: spec path (or "-" for the built one), out .pos, filter direction
_PROBE = """
import json, sys
from pathlib import Path
from georef_core.gnss import kernel_loader as k
if sys.argv[1] != "-":
    k.AOT_SPEC_PATH = Path(sys.argv[1])
aot = k.prefer_aot()
from georef_core.gnss.rtk_options import RtkOptions
from georef_core.steps.gnss_solve import run_gnss_solve
run_gnss_solve(sys.argv[4], sys.argv[5], [sys.argv[6]], sys.argv[2], RtkOptions(n_bands=1, filter_direction=sys.argv[3]))
report = {"aot": aot, "mode": k.status()["mode"], "why": k.status()["why"], "numba": "numba" in sys.modules}
if aot:   # a height given as int where the compiled variant takes float64: numba's kernel, same value
    from georef_core.gnss.atmosphere_kernels import TROPO_MODELS, troposphere
    m = TROPO_MODELS["saastamoinen"]
    report["tropo_aot"] = troposphere(m, 0.6, 50.0, 0.5, 0.7)
    report["mode_before_mismatch"] = k.status()["mode"]
    report["tropo_jit"] = troposphere(m, 0.6, 50, 0.5, 0.7)
    report["mode_after_mismatch"] = k.status()["mode"]
    report["numba_after_mismatch"] = "numba" in sys.modules
print(json.dumps(report))
"""


def _probe(spec: str, out: Path, direction: str) -> dict:
    res = subprocess.run([sys.executable, "-c", _PROBE, spec, str(out), direction, str(ROVER), str(BASE), str(NAV)],
                         capture_output=True, text=True, cwd=REPO, env={**os.environ, "GEOREF_GNSS_AOT": "1"})
    assert res.returncode == 0, res.stderr[-3000:]
    return json.loads(res.stdout.strip().splitlines()[-1])


def _rows(path: Path) -> list[str]:
    return [ln for ln in path.read_text().splitlines() if not ln.startswith("%")]


def _jit_solve(tmp_path: Path, direction: str) -> Path:
    from georef_core.gnss.rtk_options import RtkOptions
    from georef_core.steps.gnss_solve import run_gnss_solve

    ref = tmp_path / f"jit_{direction}.pos"
    run_gnss_solve(ROVER, BASE, [NAV], ref, RtkOptions(n_bands=1, filter_direction=direction))
    return ref


def test_missing_or_stale_module_falls_back_to_numba(tmp_path, monkeypatch):
    """No module (a spec path that does not exist): not loaded, and why. A spec whose digest is not the
    source's: a solving process uses numba's kernels and writes what numba's kernels write."""
    monkeypatch.setattr(kernel_loader, "AOT_SPEC_PATH", tmp_path / "missing.json")
    variants, why = kernel_loader.load_aot(respect_env=False)
    assert variants is None and "not built" in why
    stale = tmp_path / "stale.json"
    stale.write_text(json.dumps({"source_sha256": "0" * 64, "files": ["georef_core/gnss/rtk_kernels.py"],
                                 "exports": []}))
    out = tmp_path / "stale.pos"
    r = _probe(str(stale), out, "forward")
    assert not r["aot"] and r["mode"] == "jit" and r["numba"], r
    assert "source changed" in r["why"]
    ref = _rows(_jit_solve(tmp_path, "forward"))
    assert _rows(out) == ref and len(ref) == 120


def test_stale_digest_is_detected():
    """The digest covers the listed files' content: one changed byte makes a different digest."""
    spec = {"files": ["georef_core/gnss/rtk_kernels.py"]}
    d = kernel_loader.source_digest(spec["files"])
    assert d == kernel_loader.source_digest(list(spec["files"]))
    assert d != kernel_loader.source_digest(spec["files"] + ["georef_core/gnss/constants.py"])
    words = kernel_loader.digest_words(d)
    assert len(words) == kernel_loader.DIGEST_WORDS and all(-(1 << 63) <= w < (1 << 63) for w in words)


@pytest.mark.skipif(kernel_loader.load_aot(respect_env=False)[0] is None,
                    reason="ahead-of-time module not built or stale (python -m georef_core.gnss.aot_build)")
def test_aot_solve_matches_numba_and_imports_no_numba(tmp_path):
    """Forward and combined solves of the GEONET sample: the ahead-of-time process never imports numba and its
    .pos rows are those of numba's kernels; a call whose argument types no compiled variant has goes on in
    numba (imported then) with the same value."""
    for direction in ("forward", "combined"):
        out = tmp_path / f"aot_{direction}.pos"
        r = _probe("-", out, direction)
        assert r["aot"] and r["mode"] == "aot" and not r["numba"], r
        ref = _rows(_jit_solve(tmp_path, direction))
        assert len(ref) == 120 and _rows(out) == ref
    assert r["mode_before_mismatch"] == "aot"
    assert r["mode_after_mismatch"] == "jit" and r["numba_after_mismatch"]
    assert r["tropo_jit"] == r["tropo_aot"]


def test_argument_checks_follow_numba_typing():
    """The checker accepts exactly what numba would type as the compiled signature."""
    import numpy as np

    arr = kernel_loader.make_checker({"k": "array", "dtype": "float64", "ndim": 2, "layout": "C"})
    assert arr(np.zeros((3, 2)))
    assert not arr(np.zeros((3, 2), dtype=np.int64))
    assert not arr(np.zeros((3, 2, 1)))
    assert not arr(np.asfortranarray(np.zeros((3, 2))))
    assert not arr(np.zeros((3, 4))[:, ::2])
    i64, f64, b = (kernel_loader.make_checker({"k": k}) for k in ("int64", "float64", "bool"))
    assert i64(3) and i64(np.int64(3)) and not i64(True) and not i64(3.0) and not i64(np.int32(3))
    assert f64(3.0) and f64(np.float64(3)) and not f64(3) and not f64(np.float32(3))
    assert b(True) and b(np.bool_(False)) and not b(1)
