"""Benchmark: our PPK engine against RTKLIB demo5 (pyrtklib5, EX 2.5.0, in this same process) on the same
files and configurations. Prints, per case: epochs per second for both and the ratio (ours / demo5, > 1
means we are faster), fix rates, agreement on epochs both fix (as they are, and judged: with the fixes the
carrier phase refutes where the two part by more than 5 cm counted as failures, judged_comparison.py), and
where our time goes. Both engines read
the files, solve and write a .pos file; the two run alternately and each engine's best time of the repeats
is used (the least disturbed by other processes on a shared machine). For forward (or backward) runs both
engines also run the other way once, untimed: the judge's witnesses where the carrier phase is not decisive.

Whole process: what a surveyor waits for, start to .pos written, as a fresh process for each engine (median
of --process-repeat runs, the engines alternating): ours is the `georef gnss solve ... --rtklib-conf CONF`
command (console script; it also writes the Parquet, events CSV and summary JSON); demo5's is a fresh
`python -c` that imports pyrtklib5 and runs postpos on the same files and configuration (there is no
rnx2rtkp binary here; the import costs ~0.04 s). Printed beside the in-process figures as seconds and the
ratio demo5 / ours (> 1: our command finishes first). numba's kernel cache must be warm (`georef warmup`),
or the first of our runs compiles.

Our whole process's fixed cost (--breakdown N: N fresh processes of the first case, median): the
interpreter's start, importing numpy, numba and our modules, numba's target set-up (the first kernel call's
typing and lowering registries), loading the cached kernels the solve calls, reading the files, the solve,
writing the outputs, and the other first-call costs (lazy imports such as pyarrow). --before DIR times a
copy of georef_core from before a change (DIR/georef_core, its numba cache copied with it) as a third
fresh process in the same rounds, so that before and after are measured on the same machine in the same run.
Our modules are byte-compiled first (as an installed package is; with PYTHONDONTWRITEBYTECODE set, as here
and in the Dockerfile, a process would otherwise compile ~40 modules from source each time).

    python bench/gnss_vs_rtklib.py            # the seven cases of shared/data/README.md
    python bench/gnss_vs_rtklib.py --all      # every reference case
    python bench/gnss_vs_rtklib.py --repeat 5 car
    python bench/gnss_vs_rtklib.py --repeat 1 --breakdown 5 --before /tmp/georef_before --all
    python bench/gnss_vs_rtklib.py --repeat 1 --process-repeat 3 --jit-baseline --all

With the kernels compiled ahead of time (`python -m georef_core.gnss.aot_build`, run by `make install`),
`georef gnss solve` does not import numba (georef_core/gnss/kernel_loader.py); --jit-baseline times the
same command with GEOREF_GNSS_AOT=0 (numba's JIT cache, as before) as the "before" column, checks that its
.pos is byte-identical, and the breakdown shows both processes.

Cold and warm: "ours" is the command with no resident solver (GEOREF_GNSS_SERVER=0: the whole fresh
process); "warm" is the same command handed to a resident solver (`georef gnss server`, started before the
cases in its own run folder, not timed), measured start to .pos written as the user's command sees it; its CPU
seconds are the client's plus the server's own and its solve processes' (/proc/PID/stat). The warm .pos must
be the same bytes as the cold one (a note is printed otherwise). --no-warm skips it.
"""

from __future__ import annotations

import argparse
import atexit
import compileall
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from georef_core.gnss.input_files import load_navigation, load_observations  # noqa: E402
from tests.gnss.judged_comparison import judge_fixes  # noqa: E402
from georef_core.gnss.ppk import prepare, solve_files  # noqa: E402
from georef_core.gnss.rtk_options import read_rtklib_conf  # noqa: E402
from georef_core.gnss.solution_io import read_pos, write_pos  # noqa: E402
from tests.gnss.rtklib_cases import reference_cases, reverse_passes, run_demo5  # noqa: E402

DEFAULT = [("cssrlib_2021_265_car_kinematic", "kinematic_l1l2_fwd_fah"),
           ("cssrlib_2021_265_car_kinematic", "kinematic_l1_fwd_fah"),
           ("matrtklib_static_1m", "kinematic_l1l2_fwd_fah"),
           ("matrtklib_static_1m", "kinematic_l1l2_comb_fah"),
           ("ublox_m8p_20181004_walk", "kinematic_l1_fwd_fah"),
           ("ublox_m8p_20181004_walk", "kinematic_l1_comb_fah"),
           ("rtklib_gsi_0759_3040_static", "static_l1l2_fwd_fah")]


def run_ours(conf, rover, base, navs, out):
    opts = read_rtklib_conf(conf).options
    t0 = time.perf_counter()
    sol = solve_files(rover, base, navs, opts)
    write_pos(out, sol)
    return time.perf_counter() - t0, sol


_DEMO5_PROCESS = """
import sys
import pyrtklib5 as rtk
conf, out, files = sys.argv[1], sys.argv[2], sys.argv[3:]
rtk.resetsysopts()
rtk.loadopts(conf, rtk.sysopts[0])
popt, sopt, fopt = rtk.prcopt_t(), rtk.solopt_t(), rtk.filopt_t()
rtk.getsysopts(popt, sopt, fopt)
sys.exit(rtk.postpos(rtk.gtime_t(), rtk.gtime_t(), 0.0, 0.0, popt, sopt, fopt, files, len(files), out, "", ""))
"""


def _georef_command(tree: Path | None = None) -> list[str]:
    """The `georef` command: the console script, or (tree: a folder holding a georef_core copy) the same
    entry point run from that copy."""
    if tree is not None:
        return [sys.executable, "-c", f"import sys; sys.path.insert(0, {str(tree)!r}); "
                "from georef_core.cli.main import main; sys.exit(main())"]
    script = Path(sys.executable).with_name("georef")
    return [str(script)] if script.exists() else [sys.executable, "-m", "georef_core.cli.main"]


# one fresh process of ours, instrumented: where the fixed cost goes (seconds since the previous mark); its
# first and last parts are shared by the numba path and the ahead-of-time path (``loads``: the numba cache
# loads timed, None where numba is not used)
_PROBE_HEAD = """
import json, sys, time
t0 = time.process_time()
marks = {}
def mark(name):
    global t0
    t = time.process_time(); marks[name] = t - t0; t0 = t
sys.path.insert(0, sys.argv[1])
import numpy
mark("import numpy")
"""

_PROBE_SOLVE = """
solving = []
_solve_files = gnss_solve.solve_files
def solve_files(*a, **k):
    t, w = time.process_time(), time.perf_counter()
    sol = _solve_files(*a, **k)
    solving.append((time.process_time() - t, time.perf_counter() - w, dict(sol.timings_s)))
    return sol
gnss_solve.solve_files = solve_files
conf, out, rover, base, navs = sys.argv[2], sys.argv[3], sys.argv[4], sys.argv[5], sys.argv[6:]
opts = read_rtklib_conf(conf).options
gnss_solve.run_gnss_solve(rover, base, navs, out, opts)
first = time.process_time() - t0
t = time.process_time()
gnss_solve.run_gnss_solve(rover, base, navs, out, opts)    # again: the same work without first-call costs
total = time.process_time() - t
solve_s, solve_wall, timings = solving[-1]
if loads is not None:
    marks["kernel loads"] = sum(loads)
marks["reading"] = solve_s * min(1.0, timings.get("load", 0.0) / solve_wall)   # its share of the wall time
marks["solve"] = solve_s - marks["reading"]
marks["writing"] = total - solve_s
marks["other first-call costs"] = first - total - sum(loads or ())
marks["kernels loaded"] = len(loads or ())
"""

_BREAKDOWN_PROCESS = _PROBE_HEAD + """import numba
mark("import numba")
from georef_core.cli import gnss_commands
from georef_core.gnss.rtk_options import read_rtklib_conf
from georef_core.steps import gnss_solve
mark("import georef_core")
try:
    from georef_core.cli.numba_start import trim_numba_start
except ImportError:   # a tree from before it
    trim_numba_start = lambda: None
trim_numba_start()
from numba.core.registry import cpu_target
cpu_target.target_context.refresh()
mark("numba target set-up")
from numba.core import caching
loads = []
_load = caching.Cache.load_overload
def load_overload(self, sig, ctx):
    t = time.process_time()
    try:
        return _load(self, sig, ctx)
    finally:
        loads.append(time.process_time() - t)
caching.Cache.load_overload = load_overload
""" + _PROBE_SOLVE + """print(json.dumps(marks))
"""

# the same with the ahead-of-time kernels (kernel_loader.prefer_aot): numba is not imported
_BREAKDOWN_AOT_PROCESS = _PROBE_HEAD + """from georef_core.gnss import kernel_loader
if not kernel_loader.prefer_aot():
    raise SystemExit("the ahead-of-time kernels are not usable: " + kernel_loader.status()["why"])
mark("load the ahead-of-time kernels")
from georef_core.cli import gnss_commands
from georef_core.gnss.rtk_options import read_rtklib_conf
from georef_core.steps import gnss_solve
mark("import georef_core")
loads = None
""" + _PROBE_SOLVE + """if "numba" in sys.modules or kernel_loader.status()["mode"] != "aot":
    raise SystemExit("numba was imported: " + kernel_loader.status()["why"])
print(json.dumps(marks))
"""

_STARTUP_PROCESS = "pass"


def fixed_cost_breakdown(tree: Path, conf, rover, base, navs, tmp: Path, repeat: int, aot: bool = False) -> dict:
    """Median over `repeat` fresh processes of each part of our process's CPU time (seconds), the
    interpreter's own start (`python -c pass`) included."""
    files = [str(f) for f in (rover, base, *navs)]
    runs = []
    for _ in range(repeat):
        cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        subprocess.run([sys.executable, "-c", _STARTUP_PROCESS], check=True)
        cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        start = (cpu1.ru_utime - cpu0.ru_utime) + (cpu1.ru_stime - cpu0.ru_stime)
        res = subprocess.run([sys.executable, "-c", _BREAKDOWN_AOT_PROCESS if aot else _BREAKDOWN_PROCESS, str(tree), str(conf),
                              str(tmp / "breakdown.pos"), *files], capture_output=True, text=True)
        if res.returncode != 0:
            raise RuntimeError(f"breakdown process failed: {res.stderr[-2000:]}")
        runs.append({"interpreter start": start, **json.loads(res.stdout.strip().splitlines()[-1])})
    return {k: statistics.median(r[k] for r in runs) for k in runs[0]}


def print_breakdown(label: str, parts: dict) -> None:
    n = parts.pop("kernels loaded")
    total = sum(parts.values())
    print(f"{label}: {total:.2f} s = " + ", ".join(f"{k} {v:.3f}" for k, v in parts.items())
          + f" ({n:.0f} kernels loaded)")


def byte_compile(tree: Path) -> None:
    """.pyc files for our modules, as an installed package has them (quiet; only what is out of date)."""
    compileall.compile_dir(str(tree / "georef_core"), quiet=1)


def _timed(cmd, out: Path, env: dict | None = None, server_pid: int | None = None) -> tuple[float, float]:
    """Wall seconds of the process, and its CPU seconds (user + system: less disturbed than the wall
    time by other work on a shared machine). server_pid: the resident solver's CPU seconds over the same
    time (its own and its reaped solve processes') are added: the solve runs there."""
    out.unlink(missing_ok=True)
    cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    s0 = _server_cpu_s(server_pid)
    t0 = time.perf_counter()
    res = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)
    elapsed = time.perf_counter() - t0
    cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if res.returncode != 0 or not out.exists():
        raise RuntimeError(f"{cmd[0]} failed ({res.returncode}): {res.stderr[-2000:]}")
    if server_pid is not None and "solving in this process" in res.stderr:
        raise RuntimeError(f"the resident solver did not run {out.name}: {res.stderr[-500:]}")
    return elapsed, (cpu1.ru_utime - cpu0.ru_utime) + (cpu1.ru_stime - cpu0.ru_stime) + _server_cpu_s(server_pid) - s0


def _server_cpu_s(pid: int | None) -> float:
    """utime + stime + cutime + cstime of a process (/proc/PID/stat), seconds; 0 without a pid."""
    if pid is None:
        return 0.0
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return sum(int(x) for x in fields[11:15]) / os.sysconf("SC_CLK_TCK")


class ResidentSolver:
    """`georef gnss server` for the warm figures: its own run folder, started (not niced, not timed) before
    the cases and stopped after them. The cold figures run with GEOREF_GNSS_SERVER=0 (no server)."""

    def __init__(self, tmp: Path):
        self.run_dir = tmp / "run"
        self.run_dir.mkdir(mode=0o700, exist_ok=True)
        self.env = {**os.environ, "GEOREF_RUN_DIR": str(self.run_dir), "GEOREF_GNSS_SERVER": "manual"}
        self.pid = None
        self.restarts = -1

    def status(self) -> dict:
        res = subprocess.run([*_georef_command(None), "gnss", "server", "status", "--json"], capture_output=True,
                             text=True, env=self.env)
        return json.loads(res.stdout)

    def start(self) -> None:
        """Start it and wait until its spare process is warmed (as it is between a user's solves)."""
        res = subprocess.run([*_georef_command(None), "gnss", "server", "start", "--wait", "120", "--idle-s",
                              "3600"], capture_output=True, text=True, env=self.env)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            info = self.status()
            if info.get("running") and info.get("spare") in ("ready", None):
                break
            time.sleep(0.1)
        if res.returncode != 0 or not info.get("running"):
            raise RuntimeError(f"resident solver not started: {res.stdout} {res.stderr}")
        self.pid = info["pid"]
        self.restarts += 1

    def ensure(self) -> None:
        """A server for the sources as they are now (in a working tree others edit, the one started
        earlier may have exited: its digest changed)."""
        if self.pid is None or not Path(f"/proc/{self.pid}").exists() or not self.status().get("running"):
            self.start()

    def stop(self) -> None:
        if self.pid is not None:
            subprocess.run([*_georef_command(None), "gnss", "server", "stop"], capture_output=True, env=self.env)


def whole_process_times(conf, rover, base, navs, tmp: Path, repeat: int,
                        before: Path | None = None, jit_baseline: bool = False,
                        server: ResidentSolver | None = None) -> dict[str, tuple[float, float]]:
    """Median seconds of a fresh process, start to .pos written: demo5 (python -c + pyrtklib5.postpos), ours
    (georef gnss solve) and, with `before` (a folder holding an earlier georef_core), that copy's command;
    alternating: {"demo5" | "ours" | "before": (median wall s, median CPU s)}. The before copy's .pos must be
    the same bytes as ours."""
    files = [str(f) for f in (rover, base, *navs)]
    demo5 = [sys.executable, "-c", _DEMO5_PROCESS, str(conf), str(tmp / "proc_demo5.pos"), *files]
    solve = ["gnss", "solve", *files, "--rtklib-conf", str(conf), "--out"]
    ours = [*_georef_command(REPO if before else None), *solve, str(tmp / "proc_ours.pos")]
    old = [*_georef_command(before), *solve, str(tmp / "proc_before.pos")] if before else None
    old_env = None
    if jit_baseline:   # the same command on numba's JIT path (kernel_loader.py)
        old, old_env = ([*_georef_command(None), *solve, str(tmp / "proc_before.pos")],
                        {**os.environ, "GEOREF_GNSS_AOT": "0", "GEOREF_GNSS_SERVER": "0"})
    cold_env = {**os.environ, "GEOREF_GNSS_SERVER": "0"}   # no resident solver: a whole fresh process
    if old and old_env is None:
        old_env = cold_env
    warm = [*_georef_command(None), *solve, str(tmp / "proc_warm.pos")] if server else None
    runs = {"demo5": [], "ours": [], "before": [], "warm": []}
    for _ in range(repeat):
        runs["demo5"].append(_timed(demo5, tmp / "proc_demo5.pos"))
        runs["ours"].append(_timed(ours, tmp / "proc_ours.pos", cold_env))
        if old:
            runs["before"].append(_timed(old, tmp / "proc_before.pos", old_env))
        if warm:
            server.ensure()
            try:
                runs["warm"].append(_timed(warm, tmp / "proc_warm.pos", server.env, server.pid))
            except (RuntimeError, OSError):   # the sources changed under it: once more, with a fresh server
                server.start()
                runs["warm"].append(_timed(warm, tmp / "proc_warm.pos", server.env, server.pid))
    if old and (tmp / "proc_before.pos").read_bytes() != (tmp / "proc_ours.pos").read_bytes():
        print(f"  note: {conf.name}: the before copy's .pos differs from ours (not the same engine?)")
    if warm and (tmp / "proc_warm.pos").read_bytes() != (tmp / "proc_ours.pos").read_bytes():
        print(f"  note: {conf.name}: the resident solver's .pos differs from the fresh process's")
    return {k: (statistics.median(w for w, _ in v), statistics.median(c for _, c in v)) for k, v in runs.items() if v}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("select", nargs="*", help="substrings of dataset/case to run")
    ap.add_argument("--all", action="store_true")
    ap.add_argument("--repeat", type=int, default=5, help="runs per engine; the best time is reported")
    ap.add_argument("--process-repeat", type=int, default=5,
                    help="whole-process runs per engine (fresh processes); the median is reported (0: skip)")
    ap.add_argument("--breakdown", type=int, default=3, metavar="N",
                    help="fresh instrumented processes for the fixed-cost breakdown (median; 0: skip)")
    ap.add_argument("--before", type=Path, metavar="DIR",
                    help="a folder holding a copy of georef_core from before a change: timed beside ours")
    ap.add_argument("--jit-baseline", action="store_true",
                    help="time our command on numba's JIT path (GEOREF_GNSS_AOT=0) as the before column")
    ap.add_argument("--no-warm", action="store_true",
                    help="whole process: skip the warm figures (the command handed to a running resident solver)")
    args = ap.parse_args()
    if args.before is not None and args.jit_baseline:
        print("--before and --jit-baseline: one or the other")
        return 1
    if args.before is not None and not (args.before / "georef_core" / "cli" / "main.py").is_file():
        print(f"--before {args.before}: no georef_core/cli/main.py there")
        return 1
    cases = reference_cases()
    if not cases:
        print("shared/data/gnss not found (set GEOREF_SHARED_DATA)")
        return 1
    if args.select:
        cases = [c for c in cases if any(s in f"{c[0]}/{c[1]}" for s in args.select)]
    elif not args.all:
        cases = [c for c in cases if (c[0], c[1]) in DEFAULT]
    # warm-up: numba kernels are compiled (or loaded from cache) on first use
    tmp = Path(tempfile.mkdtemp())
    run_ours(cases[0][5], cases[0][2], cases[0][3], cases[0][4], tmp / "warm.pos")
    for tree in (REPO, args.before):
        if tree is not None:
            byte_compile(tree)
    if args.breakdown > 0:
        ds, name, rover, base, navs, conf = cases[0][:6]
        print(f"our fixed cost, {ds}/{name} (median of {args.breakdown} fresh processes, CPU seconds):")
        from georef_core.gnss import kernel_loader

        aot_now = kernel_loader.load_aot()[0] is not None
        for label, tree, aot in (("before", args.before, False), ("numba JIT path", REPO if args.jit_baseline else None, False),
                                 ("now" + (" (ahead-of-time kernels)" if aot_now else ""), REPO, aot_now)):
            if tree is not None:
                print_breakdown(f"  {label}", fixed_cost_breakdown(tree, conf, rover, base, navs, tmp, args.breakdown, aot))
    print("in-process: epochs per second, ratio ours/demo5 (best of --repeat); whole process (fresh processes, "
          "median of --process-repeat): seconds start to .pos written, ratio demo5/ours (> 1: ours finishes first)")
    print(f"{'dataset/case':52s} {'epochs':>6s} {'demo5 ep/s':>10s} {'ours ep/s':>10s} {'ratio':>6s} "
          f"{'proc demo5 s':>12s} {'proc ours s':>11s} {'ratio':>6s} "
          f"{'fix demo5':>9s} {'fix ours':>8s} {'medH mm':>7s} {'medV mm':>7s} {'>5cm':>5s} | judged: {'fix demo5':>9s} "
          f"{'medH mm':>7s} {'medV mm':>7s} {'>5cm':>5s} {'refuted demo5/ours':>18s} {'by reverse':>10s} "
          "| our time split (s)")
    ratios, proc_ratios, cpu_ratios, before_ratios, warm_ratios = [], [], [], [], []
    server = None
    if args.process_repeat > 0 and not args.no_warm:
        server = ResidentSolver(tmp)
        server.start()
        atexit.register(server.stop)
    for ds, name, rover, base, navs, conf, ref in cases:
        d_times, o_times = [], []
        for _ in range(args.repeat):
            d_times.append(run_demo5(conf, [rover, base, *navs], tmp / "demo5.pos"))
            t, sol = run_ours(conf, rover, base, navs, tmp / "ours.pos")
            o_times.append(t)
        n = len(sol.time_s)
        td, to = min(d_times), min(o_times)
        opts = read_rtklib_conf(conf).options
        data = prepare(load_observations(rover).observations, load_observations(base).observations,
                       load_navigation(navs), opts)[0]
        # forward or backward runs: both engines' passes the other way are the judge's witnesses (untimed)
        reverse = reverse_passes(conf, rover, base, navs, tmp)
        j = judge_fixes(data, opts, read_pos(tmp / "ours.pos"), read_pos(tmp / "demo5.pos"), **reverse)
        c, g = j.raw, j.judged
        split = ", ".join(f"{k} {v:.2f}" for k, v in sol.timings_s.items() if v >= 0.01)
        ratios.append(td / to)
        if args.process_repeat > 0:
            w = whole_process_times(conf, rover, base, navs, tmp, args.process_repeat, args.before, args.jit_baseline,
                                    server)
            (pd_s, pd_cpu), (po_s, po_cpu) = w["demo5"], w["ours"]
            proc_ratios.append(pd_s / po_s)
            cpu_ratios.append(pd_cpu / po_cpu)
            proc = f"{pd_s:12.2f} {po_s:11.2f} {pd_s / po_s:6.2f} (CPU s {pd_cpu:.2f} / {po_cpu:.2f}: {pd_cpu / po_cpu:.2f}"
            if "before" in w:
                pb_s, pb_cpu = w["before"]
                before_ratios.append((pd_s / pb_s, pd_cpu / pb_cpu))
                proc += f"; before {pb_s:.2f} s: {pd_s / pb_s:.2f}, CPU {pb_cpu:.2f} s: {pd_cpu / pb_cpu:.2f}"
            if "warm" in w:
                pw_s, pw_cpu = w["warm"]
                warm_ratios.append((pd_s / pw_s, pd_cpu / pw_cpu))
                proc += f"; warm {pw_s:.2f} s: {pd_s / pw_s:.2f}, CPU {pw_cpu:.2f} s: {pd_cpu / pw_cpu:.2f}"
            proc += ") "
        else:
            proc = f"{'-':>12s} {'-':>11s} {'-':>6s} "
        print(f"{ds + '/' + name:52s} {n:6d} {n / td:10.0f} {n / to:10.0f} {td / to:6.2f} {proc}"
              f"{100 * c.fix_rate_ref:8.1f}% {100 * c.fix_rate:7.1f}% {1000 * c.median_horizontal_m:7.1f} "
              f"{1000 * c.median_vertical_m:7.1f} {c.n_beyond_5cm:5d} |         {100 * g.fix_rate_ref:8.1f}% "
              f"{1000 * g.median_horizontal_m:7.1f} {1000 * g.median_vertical_m:7.1f} {g.n_beyond_5cm:5d} "
              f"{j.n_refuted_ref:12d}/{j.n_refuted_ours:<5d} {j.n_refuted_by_reverse:10d} | {split}")
    print(f"\nspeed ratio ours/demo5 (epochs per second, >1 = faster): median {statistics.median(ratios):.2f}, "
          f"min {min(ratios):.2f}, max {max(ratios):.2f} over {len(ratios)} cases")
    if proc_ratios:
        print(f"whole-process ratio demo5/ours, cold (no resident solver; seconds, >1 = faster): median {statistics.median(proc_ratios):.2f}, "
              f"min {min(proc_ratios):.2f}, max {max(proc_ratios):.2f} over {len(proc_ratios)} cases")
        print(f"  in CPU seconds: median {statistics.median(cpu_ratios):.2f}, min {min(cpu_ratios):.2f}, "
              f"max {max(cpu_ratios):.2f}")
        print(f"  cases where ours finishes first (ratio >= 1): {sum(r >= 1 for r in proc_ratios)} of {len(proc_ratios)} "
              f"in seconds, {sum(r >= 1 for r in cpu_ratios)} of {len(cpu_ratios)} in CPU seconds")
    if server is not None:
        server.stop()
        if server.restarts:
            print(f"  (the resident solver was started again {server.restarts} time(s): georef_core changed while "
                  "the bench ran)")
    from georef_core.gnss import kernel_loader as kl

    print("ahead-of-time kernels at the end: " + ("current" if kl.load_aot(respect_env=False)[0] is not None
                                                  else "STALE (the cold figures used numba's JIT path)"))
    if warm_ratios:
        for i, what in enumerate(("seconds", "CPU seconds")):
            r = [b[i] for b in warm_ratios]
            print(f"  warm (resident solver running), in {what}: median {statistics.median(r):.2f}, "
                  f"min {min(r):.2f}, max {max(r):.2f}, ratio >= 1 in {sum(x >= 1 for x in r)} of {len(r)}")
    if before_ratios:
        for i, what in enumerate(("seconds", "CPU seconds")):
            r = [b[i] for b in before_ratios]
            print(f"  before the change, same rounds, in {what}: median {statistics.median(r):.2f}, "
                  f"min {min(r):.2f}, max {max(r):.2f}, ratio >= 1 in {sum(x >= 1 for x in r)} of {len(r)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
