"""The fixed cost of `georef gnss solve`: what its process imports, the warm-up that compiles every numba kernel
ahead (georef_core/warmup.py, run by `make install`), the first-run notice and the solve's progress stages."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from georef_core import warmup
from georef_core.cli.main import main

DATA = Path(__file__).resolve().parents[1] / "data" / "gnss" / "gsi_0759_3040"
ROVER, BASE, NAV = DATA / "07590920.05o", DATA / "30400920.05o", DATA / "07590920.05n"

# heavy packages a GNSS solve has no use for (photogrammetry, rasters, plotting, web stack, pandas)
HEAVY = ("pycolmap", "open3d", "matplotlib", "rasterio", "cv2", "laspy", "shapely", "reportlab", "pandas",
         "fastapi", "sqlalchemy", "celery", "backend", "worker")

_PROBE = """
import sys, types
import numpy as np
from georef_core.cli.main import main
try:
    main(["gnss", "solve", "--help"])
except SystemExit:
    pass
from georef_core.steps import gnss_solve            # what cmd_solve imports
from georef_core.gnss.solution_io import write_parquet
n = 3
sol = types.SimpleNamespace(
    time_s=np.arange(n, dtype=float), receiver_time_s=np.arange(n, dtype=float), status=np.array([1, 2, 0]),
    position_ecef_m=np.tile([-3978241.958, 3382840.234, 3649900.853], (n, 1)), covariance_ecef_m2=np.tile(np.eye(3), (n, 1, 1)),
    velocity_ecef_m_s=np.zeros((n, 3)), velocity_covariance_m2_s2=np.tile(np.eye(3), (n, 1, 1)),
    n_sats=np.array([8, 7, 0]), ratio=np.array([5.0, 1.0, 0.0]), age_s=np.zeros(n),
    residuals_m=np.full((n, 2, 1), 0.001), sat_ids=["G01", "G02"])
write_parquet(sys.argv[1], sol)
print(" ".join(sorted({m.split(".")[0] for m in sys.modules})))
"""


def test_gnss_command_imports_nothing_heavy(tmp_path):
    out = subprocess.run([sys.executable, "-c", _PROBE, str(tmp_path / "t.parquet")], capture_output=True,
                         text=True, check=True).stdout.split()
    assert not [m for m in HEAVY if m in out], f"imported by the gnss command path: {[m for m in HEAVY if m in out]}"
    import pyarrow.parquet as pq

    table = pq.read_table(tmp_path / "t.parquet")
    assert table.column("quality").to_pylist() == ["fix", "float", "none"]
    assert table.schema.field("status").type == "int8" and table.schema.field("x_ecef_m").type == "double"
    res = pq.read_table(tmp_path / "t_residuals.parquet")
    assert res.column("sat").to_pylist() == ["G01", "G02"] * 3


def test_warmup_covers_every_kernel():
    """Every numba dispatcher of georef_core is an entry point of a warm-up stage or called (transitively)
    by one, so `georef warmup` leaves nothing for a first solve to compile. Checked on the bytecode: nothing
    is compiled here."""
    found = warmup.discover_dispatchers()
    assert len(found) > 50 and "georef_core.gnss.rtk_kernels.filter_pass" in found
    entry = [n for st in warmup.STAGES for n in st.entry_points]
    assert not [n for n in entry if n not in found], "a stage names a kernel that no longer exists"
    covered = warmup.covered(entry, found)
    assert sorted(set(found) - covered) == [], "kernels no warm-up stage reaches: add them to warmup.STAGES"
    assert all(d._cache is not None and type(d._cache).__name__ != "NullCache" for d in found.values()), \
        "every kernel is @njit(cache=True)"


def test_warmup_callee_scan_follows_module_attributes():
    found = warmup.discover_dispatchers()
    names = {warmup.qualified_name(d) for d in warmup.callees(found["georef_core.gnss.rtk_kernels.filter_pass"])}
    assert "georef_core.gnss.rtk_kernels.resolve_epoch" in names
    assert "georef_core.gnss.ambiguity_kernels.resolve" in warmup.covered(
        ["georef_core.gnss.rtk_kernels.filter_pass"], found)


def test_first_run_notice_and_solve_progress(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(warmup, "gnss_kernels_cached", lambda: False)
    rc = main(["gnss", "solve", str(ROVER), str(BASE), str(NAV), "--out", str(tmp_path / "s.pos"), "--freq", "l1",
               "--filter", "combined"])
    err = capsys.readouterr().err
    assert rc == 0 and "first run: compiling the GNSS kernels" in err

    from georef_core.gnss.rtk_options import RtkOptions
    from georef_core.steps.gnss_solve import _solve_progress, run_gnss_solve

    seen = []
    run_gnss_solve(ROVER, BASE, [NAV], tmp_path / "p.pos", RtkOptions(n_bands=1),
                   progress=_solve_progress(lambda *a: seen.append(a)))
    assert [(d, t) for _, d, t in seen] == [(0, 4), (1, 4), (2, 4), (3, 4)]
    assert seen[0][0].startswith("gnss: reading the files (first run: compiling the kernels")
    assert "backward pass" in seen[3][0]


_SOLVE_PROBE = """
import sys
from georef_core.cli.main import main
rc = main(["gnss", "solve", *sys.argv[1:4], "--out", sys.argv[4], "--freq", "l1", "--filter", "forward"])
from numba.core.typing import cffi_utils
import cffi   # importable again after numba's typing was set up without it
from llvmlite.binding import ffi
events = any("llvm_lock" in getattr(a, "__qualname__", "") for a, _ in ffi.lib._lock._cblist)
print(rc, "scipy.linalg" in sys.modules, "pycparser" in sys.modules, cffi_utils.SUPPORTED,
      "scipy.linalg.cython_lapack" in sys.modules, events)
"""


def test_gnss_solve_process_skips_what_numba_loads_for_nothing(tmp_path):
    """`georef gnss solve` in a fresh process: numba's target set-up neither imports scipy.linalg's Python API
    (only its BLAS/LAPACK function tables, which the kernels call) nor cffi's C parser, and numba's
    LLVM-lock event callbacks are off (cli/numba_start.py); the trajectory is the same as a solve in a process that loaded both."""
    out = tmp_path / "cli.pos"
    res = subprocess.run([sys.executable, "-c", _SOLVE_PROBE, str(ROVER), str(BASE), str(NAV), str(out)],
                         capture_output=True, text=True,
                         env={**os.environ, "GEOREF_GNSS_AOT": "0"})   # numba's path (kernel_loader.py)
    assert res.returncode == 0, res.stderr[-2000:]
    rc, linalg, pycparser, cffi_typing, lapack, lock_events = res.stdout.split()[-6:]
    assert rc == "0" and lapack == "True" and lock_events == "False"
    assert linalg == "False", "something in the gnss solve path imports scipy.linalg's package (see numba_start.py)"
    assert pycparser == "False" and cffi_typing == "False"

    import scipy.linalg  # noqa: F401  (this process: scipy.linalg and numba's cffi support loaded as usual)
    from georef_core.gnss.rtk_options import RtkOptions
    from georef_core.steps.gnss_solve import run_gnss_solve

    ref = tmp_path / "ref.pos"
    run_gnss_solve(ROVER, BASE, [NAV], ref, RtkOptions(n_bands=1, filter_direction="forward"))
    rows = [[ln for ln in p.read_text().splitlines() if not ln.startswith("%")] for p in (out, ref)]
    assert len(rows[0]) == 120 and rows[0] == rows[1]
