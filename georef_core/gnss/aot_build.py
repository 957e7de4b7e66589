"""Build the GNSS kernels ahead of time (``numba.pycc``) into ``georef_core/gnss/_gnss_kernels_aot*.so``.

``make install`` (after ``georef warmup``) and the Dockerfile run ``python -m georef_core.gnss.aot_build``.
It compiles the kernels that the solve and the engine checks call from Python (the entry points of
:data:`georef_core.warmup.STAGES`, groups "gnss" and "gnss-checks"), each for the argument types the
warm-up's public code paths call it with in the build's own process (production's; not whatever else
numba's cache may hold from tests), and
writes beside the module a JSON description: the source files and their digest, and each exported
variant's argument types (what kernel_loader checks before it calls one). The kernels they call are
compiled into them. Nothing here changes a kernel: the same Python functions, compiled by the same numba,
for the host CPU by default (as numba's JIT does).

A failure (no C compiler, a type pycc cannot export) prints why and exits 0 without a module: the solve
then uses numba's JIT cache, as before. ``--check`` says whether the module is present and current.
"""

from __future__ import annotations

import argparse
import ast
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("GEOREF_GNSS_AOT", "0")   # this process compiles: the kernels must be numba's

from . import kernel_loader  # noqa: E402

GROUPS = ("gnss", "gnss-checks")


def describe_type(t) -> dict:
    """JSON description of a numba argument type that kernel_loader can check; ValueError otherwise."""
    from numba.core import types

    if isinstance(t, types.Array):
        if t.layout not in ("C", "A") or not t.aligned:
            raise ValueError(f"array layout {t.layout} not supported")
        return {"k": "array", "dtype": str(t.dtype), "ndim": t.ndim, "layout": t.layout}
    if isinstance(t, types.Boolean):
        return {"k": "bool"}
    if isinstance(t, types.Literal):
        raise ValueError(f"literal argument {t}")
    if t == types.int64:
        return {"k": "int64"}
    if t == types.float64:
        return {"k": "float64"}
    if isinstance(t, types.BaseNamedTuple):
        cls = t.instance_class
        return {"k": "namedtuple", "cls": f"{cls.__module__}.{cls.__qualname__}",
                "items": [describe_type(x) for x in t.types]}
    if isinstance(t, types.BaseTuple):
        return {"k": "tuple", "items": [describe_type(x) for x in t.types]}
    raise ValueError(f"argument type {t} not supported")


def _local_imports(path: Path) -> set[Path]:
    """georef_core modules a module imports (relative or absolute), as files."""
    pkg_root = kernel_loader.PACKAGE_DIR.parent
    rel = path.relative_to(pkg_root).with_suffix("")
    parts = list(rel.parts[:-1])
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        names = []
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = parts[:len(parts) - (node.level - 1)] if node.level > 1 else parts
                mod = base + (node.module.split(".") if node.module else [])
            else:
                mod = (node.module or "").split(".")
            names = [mod] + [mod + [a.name] for a in node.names]
        elif isinstance(node, ast.Import):
            names = [a.name.split(".") for a in node.names]
        for n in names:
            if not n or n[0] != "georef_core":
                continue
            for cand in (pkg_root.joinpath(*n).with_suffix(".py"), pkg_root.joinpath(*n, "__init__.py")):
                if cand.is_file():
                    out.add(cand)
    return out


def source_files(kernel_modules: list[str]) -> list[str]:
    """The kernel modules' files and, transitively, the georef_core modules they import (relative paths)."""
    pkg_root = kernel_loader.PACKAGE_DIR.parent
    todo = [pkg_root.joinpath(*m.split(".")).with_suffix(".py") for m in kernel_modules]
    seen: set[Path] = set()
    loader = Path(kernel_loader.__file__).resolve()   # the decorator's module: no compiled code comes from it
    while todo:
        p = todo.pop()
        if p in seen or p == loader:
            continue
        seen.add(p)
        todo.extend(_local_imports(p) - seen)
    return sorted(str(p.relative_to(pkg_root)) for p in seen)


def entry_points() -> list[str]:
    from .. import warmup

    return [n for st in warmup.STAGES if st.group in GROUPS for n in st.entry_points]


def build(target_cpu: str = "host", verbose: bool = True) -> dict:
    """Compile the module; returns {"exports": n, "skipped": [...], "seconds": s}. Raises on failure."""
    import importlib

    from numba.pycc import CC

    from .. import warmup

    t0 = time.perf_counter()
    compiler = os.environ.get("CC", "cc").split()[0]
    if not (shutil.which(compiler) or shutil.which("gcc")):
        raise RuntimeError(f"no C compiler ({compiler} / gcc) on PATH: pycc needs one to link the module")
    names = entry_points()
    dispatchers = {}
    for n in names:
        mod, _, fn = n.rpartition(".")
        dispatchers[n] = getattr(importlib.import_module(mod), fn)
    # the argument types production reaches: those the warm-up's public code paths call in this process
    # (loaded from numba's cache, or compiled where missing), not every type the cache holds - a test or a
    # bench may have compiled other variants into it, which would make the module depend on what ran before
    warmup.warm_up(GROUPS)
    sigs = {n: list(d.signatures) for n, d in dispatchers.items()}
    kernel_modules = sorted({m for m, _, _ in (n.rpartition(".") for n in warmup.discover_dispatchers())
                             if m.startswith("georef_core.gnss.")})
    files = source_files(kernel_modules)
    digest = kernel_loader.source_digest(files)

    exports, skipped = [], []
    with tempfile.TemporaryDirectory(prefix="georef-aot-") as tmp:
        cc = CC(kernel_loader.AOT_NAME)
        cc.output_dir = tmp
        cc.verbose = False
        if target_cpu:
            cc.target_cpu = target_cpu
        for n in names:
            for k, sig in enumerate(sigs[n]):
                try:
                    arg_specs = [describe_type(t) for t in sig]
                except ValueError as exc:
                    skipped.append(f"{n}{sig}: {exc}")
                    continue
                export = f"{n.rpartition('.')[0].rpartition('.')[2]}__{n.rpartition('.')[2]}__{k}"
                cc.export(export, sig)(dispatchers[n].py_func)
                exports.append({"name": export, "kernel": n, "args": arg_specs})
        words = kernel_loader.digest_words(digest)
        src = "def source_digest_words():\n    return (" + ", ".join(str(w) for w in words) + ",)\n"
        ns: dict = {}
        exec(compile(src, "<aot digest>", "exec"), ns)
        cc.export("source_digest_words", "UniTuple(int64, %d)()" % kernel_loader.DIGEST_WORDS)(
            ns["source_digest_words"])
        if verbose:
            print(f"  compiling {len(exports)} kernel variants with numba.pycc (target CPU {target_cpu or 'generic'}; "
                  "a few minutes) ...", flush=True)
        cc.compile()
        built = [p for p in Path(tmp).iterdir() if p.name.startswith(kernel_loader.AOT_NAME + ".")]
        if len(built) != 1:
            raise RuntimeError(f"pycc wrote {[p.name for p in Path(tmp).iterdir()]}")
        remove_built()
        shutil.copy2(built[0], kernel_loader.GNSS_DIR / built[0].name)
    spec = {"source_sha256": digest, "files": files, "target_cpu": target_cpu or "generic",
            "exports": exports, "skipped": skipped}
    tmp_spec = kernel_loader.AOT_SPEC_PATH.with_suffix(".json.tmp")
    tmp_spec.write_text(json.dumps(spec, indent=1), encoding="utf-8")
    os.replace(tmp_spec, kernel_loader.AOT_SPEC_PATH)
    return {"exports": len(exports), "skipped": skipped, "seconds": time.perf_counter() - t0}


def verify_in_fresh_process() -> tuple[bool, str]:
    """Load the module as `georef gnss solve` would, in a fresh process (numba not imported there)."""
    import subprocess

    code = ("import sys; from georef_core.gnss import kernel_loader as k; v, why = k.load_aot(respect_env=False); "
            "print('ok' if v is not None and 'numba' not in sys.modules else 'no: ' + (why or 'numba imported'))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=str(kernel_loader.PACKAGE_DIR.parent))
    out = (res.stdout.strip().splitlines() or [res.stderr.strip()[-300:]])[-1]
    return out == "ok", out


def remove_built() -> None:
    for p in kernel_loader.GNSS_DIR.iterdir():
        if p.name.startswith(kernel_loader.AOT_NAME + "."):
            p.unlink()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m georef_core.gnss.aot_build", description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true", help="build nothing: exit 0 when the module is current")
    ap.add_argument("--target-cpu", default="host",
                    help="LLVM CPU name, 'host' (default, as numba's JIT) or 'generic' (portable: a Docker image)")
    ap.add_argument("--if-stale", action="store_true", help="build only when the module is missing or stale")
    args = ap.parse_args(argv)
    variants, why = kernel_loader.load_aot(respect_env=False)
    if args.check or (args.if_stale and variants is not None):
        print("georef aot: " + ("the ahead-of-time GNSS kernels are current" if variants is not None else why))
        return 0 if variants is not None else 1
    print("georef aot: compiling the GNSS kernels ahead of time (so that `georef gnss solve` starts without numba)",
          flush=True)
    try:
        res = build("" if args.target_cpu == "generic" else args.target_cpu)
        ok, why = verify_in_fresh_process()
        if not ok:
            raise RuntimeError(f"built, but not loadable: {why}")
    except Exception as exc:   # noqa: BLE001 - never fail an install: the JIT path works without the module
        remove_built()
        kernel_loader.AOT_SPEC_PATH.unlink(missing_ok=True)
        print(f"georef aot: warning: not built ({type(exc).__name__}: {str(exc)[:500]}); `georef gnss solve` uses "
              "numba's JIT cache instead (about 1 s more per process)", file=sys.stderr)
        return 0
    for s in res["skipped"]:
        print(f"georef aot: left to numba's JIT: {s}", file=sys.stderr)
    print(f"georef aot: {res['exports']} kernel variants compiled ahead of time ({res['seconds']:.0f} s)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
