"""Check-point residual tables: per point dx, dy, dz, |d| (estimated minus surveyed, project CRS
metres: easting, northing, height) and per axis mean, std (sample, n-1) and RMSE; written as JSON and CSV."""

from __future__ import annotations

import csv
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np


@dataclass
class ResidualRow:
    name: str
    role: str                    # check | control (leave-one-out) | control (fit)
    dx_m: float
    dy_m: float
    dz_m: float
    d3_m: float
    n_images: int
    # predicted sigma E, N, h: the triangulation's (image noise), the per-flight offsets' and the adjustment's
    # globals' share (focal length etc.; georef.globals_point_cov)
    sigma_m: tuple[float, float, float] | None = None
    note: str = ""


@dataclass
class ResidualTable:
    kind: str                    # "check points", "control points (leave-one-out)", ...
    crs: str
    rows: list[ResidualRow] = field(default_factory=list)

    def stats(self) -> dict:
        return residual_statistics([(r.dx_m, r.dy_m, r.dz_m) for r in self.rows])

    def to_dict(self) -> dict:
        return {"kind": self.kind, "crs": self.crs, "convention": "d = estimated - surveyed (metres, project CRS axes)",
                "points": [asdict(r) for r in self.rows], "statistics": self.stats()}

    def write(self, json_path, csv_path) -> None:
        Path(json_path).write_text(json.dumps(self.to_dict(), indent=1))
        st = self.stats()
        with open(csv_path, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["point", "role", "dx_m", "dy_m", "dz_m", "d3_m", "n_images", "note"])
            for r in self.rows:
                w.writerow([r.name, r.role, f"{r.dx_m:.4f}", f"{r.dy_m:.4f}", f"{r.dz_m:.4f}", f"{r.d3_m:.4f}",
                            r.n_images, r.note])
            if st.get("n"):
                for lab, key in (("mean", "mean_m"), ("std", "std_m"), ("rmse", "rmse_m")):
                    vals = [st[a][key] for a in ("dx", "dy", "dz")]
                    d3 = st["3d"].get(key, "")
                    w.writerow([lab, "", *("" if v is None else f"{v:.4f}" for v in vals),
                                "" if d3 in ("", None) else f"{d3:.4f}", "", ""])

    def format_text(self) -> str:
        lines = [f"{self.kind} ({self.crs}; d = estimated - surveyed)",
                 f"{'point':<10} {'role':<22} {'dx m':>8} {'dy m':>8} {'dz m':>8} {'|d| m':>8} {'imgs':>4}"]
        for r in self.rows:
            lines.append(f"{r.name:<10} {r.role:<22} {r.dx_m:8.4f} {r.dy_m:8.4f} {r.dz_m:8.4f} {r.d3_m:8.4f} {r.n_images:4d}"
                         + (f"  {r.note}" if r.note else ""))
        st = self.stats()
        if st.get("n"):
            for lab, key in (("mean", "mean_m"), ("std", "std_m"), ("RMSE", "rmse_m")):
                v = [st[a][key] for a in ("dx", "dy", "dz")]
                d3 = st["3d"].get(key)
                lines.append(f"{lab:<33} " + " ".join("     n/a" if x is None else f"{x:8.4f}" for x in v)
                             + ("" if d3 is None else f" {d3:8.4f}"))
        return "\n".join(lines)


def residual_statistics(d_m) -> dict:
    """The statistics of a residual table, the one definition every layer shows (the API, the PDF and the
    browser read them from residuals.json): n; per axis dx, dy, dz the mean, the sample standard deviation
    (n - 1; None for one point), the RMSE and the largest absolute value; the horizontal RMSE and maximum;
    for |d| (3D) the mean, sample standard deviation, RMSE and maximum. ``d_m``: (n, 3) dx, dy, dz in metres."""
    d = np.asarray(d_m, dtype=float).reshape(-1, 3)
    n = len(d)
    if n == 0:
        return {"n": 0}
    h = np.hypot(d[:, 0], d[:, 1])
    d3 = np.linalg.norm(d, axis=1)
    out: dict = {"n": n}
    for k, name in enumerate(("dx", "dy", "dz")):
        out[name] = {"mean_m": float(d[:, k].mean()), "std_m": float(d[:, k].std(ddof=1)) if n > 1 else None,
                     "rmse_m": float(np.sqrt(np.mean(d[:, k] ** 2))), "max_abs_m": float(np.abs(d[:, k]).max())}
    out["horizontal"] = {"rmse_m": float(np.sqrt(np.mean(h ** 2))), "max_m": float(h.max())}
    out["3d"] = {"mean_m": float(d3.mean()), "std_m": float(d3.std(ddof=1)) if n > 1 else None,
                 "rmse_m": float(np.sqrt(np.mean(d3 ** 2))), "max_m": float(d3.max())}
    return out
