"""Step: PPK baseline processing. Reads the rover, base and navigation files, writes the solution as
RTKLIB .pos + Parquet (+ residuals), the antenna positions at camera events (CSV) and a JSON summary.
The CLI (`georef gnss solve`) and the worker call this same function."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..gnss.camera_events import interpolate_at_events, read_event_csv, write_event_csv
from ..gnss.ppk import solve_files
from ..gnss.rtk_options import RtkOptions
from ..gnss.solution_io import write_parquet, write_pos


def run_gnss_solve(rover_path, base_path, nav_paths, out_pos, opts: RtkOptions, events_csv=None,
                   epsg: int | None = None, parquet_path=None, events_out=None) -> dict:
    out_pos = Path(out_pos)
    out_pos.parent.mkdir(parents=True, exist_ok=True)
    sol = solve_files(rover_path, base_path, nav_paths, opts)
    write_pos(out_pos, sol)
    parquet_path = Path(parquet_path) if parquet_path else out_pos.with_suffix(".parquet")
    write_parquet(parquet_path, sol, epsg)
    events = np.asarray(sol.event_time_s, dtype=float)
    if events_csv:
        events = read_event_csv(events_csv)
    summary = {
        "epochs": int(len(sol.time_s)),
        "fix": int(np.sum(sol.status == 1)), "float": int(np.sum(sol.status == 2)), "single": int(np.sum(sol.status == 5)),
        "fix_rate": round(sol.fix_rate, 4),
        "base_position_ecef_m": [round(float(v), 4) for v in sol.base_position_ecef_m],
        "outputs": {"pos": str(out_pos), "parquet": str(parquet_path)},
        "timings_s": {k: round(v, 3) for k, v in sol.timings_s.items()},
        "warnings": sol.warnings,
    }
    if len(events):
        ev = interpolate_at_events(sol, events)
        events_out = Path(events_out) if events_out else out_pos.with_name(out_pos.stem + "_events.csv")
        write_event_csv(events_out, ev, epsg)
        summary["events"] = {"count": int(len(events)), "fixed": int(np.sum(ev.status == 1)),
                             "without_solution": int(np.sum(ev.status == 0)), "csv": str(events_out)}
    summary_path = out_pos.with_name(out_pos.stem + "_summary.json")
    summary_path.write_text(json.dumps(summary, indent=2))
    summary["outputs"]["summary"] = str(summary_path)
    return summary
