"""The GNSS kernels' decorator: numba's JIT (with its on-disk cache), or the kernels compiled ahead of time.

Every kernel of this package is written ``@njit(cache=True)`` with :func:`njit` from here. By default that
is numba's ``njit``, unchanged. A short process that solves once and ends (``georef gnss solve``) calls
:func:`prefer_aot` before it imports the kernel modules: when the extension module that ``make install``
builds (``_gnss_kernels_aot``, made by :mod:`georef_core.gnss.aot_build` with ``numba.pycc``) is present and
was compiled from the current source, the decorator returns, for each kernel, a small wrapper that calls the
ahead-of-time compiled function, and numba is not imported at all (a fresh process then spends ~1 CPU s
less before its first epoch: docs/gnss.md, "Whole process").

"Current": the module's JSON companion lists the source files the kernels were compiled from (the kernel
modules and the georef_core modules they import, whose constants numba freezes into the code) and the
SHA-256 of their content, with Python's and numpy's versions; the extension module returns the same
digest from a compiled function. Both must equal the digest of the files as they are now, or the process
uses numba as before (an edited kernel runs as edited, never a stale compiled copy).

An ahead-of-time function has fixed argument types (those of production: the signatures numba's cache
holds after ``georef warmup``), and its compiled argument unboxing checks little (an int64 array passed
where float64 was compiled would be read as float64). The wrapper therefore checks every argument against
the compiled types (dtype, dimensions, C-contiguity, Python scalar kind, named-tuple class, recursively);
when no compiled variant matches, or a kernel was not compiled ahead of time, the process switches to
numba (:func:`switch_to_jit`: real dispatchers for every kernel, put back into the kernel modules so that
numba can compile callers) and the call goes on there, with numba's cache. Results are the same either way
(the .pos files of the 44 shared cases are byte-identical, docs/gnss.md).

``GEOREF_GNSS_AOT=0`` turns the ahead-of-time path off; ``GEOREF_GNSS_AOT=1`` turns it on in any process
that imports the kernels (for tests and benchmarks).
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import json
import os
import sys
from pathlib import Path

GNSS_DIR = Path(__file__).resolve().parent
PACKAGE_DIR = GNSS_DIR.parent
AOT_NAME = "_gnss_kernels_aot"
AOT_MODULE = f"georef_core.gnss.{AOT_NAME}"
AOT_SPEC_PATH = GNSS_DIR / f"{AOT_NAME}.json"
ENV_VAR = "GEOREF_GNSS_AOT"
DIGEST_WORDS = 4   # the digest's first 4 x 64 bits, returned by the extension module's `source_digest_words`

_state = {
    "want_aot": os.environ.get(ENV_VAR) == "1",
    "mode": None,        # None until the first kernel is decorated (or prefer_aot decides): "aot" | "jit"
    "variants": {},      # qualified kernel name -> [(compiled function, argument checker, export name)]
    "why": "",           # why the ahead-of-time path is not used (or why the process switched to numba)
}
_wrappers: list["AotKernel"] = []


# ------------------------------------------------------------------------------------------ the digest

def source_digest(files: list[str]) -> str:
    """SHA-256 (hex) of the listed source files (paths relative to georef_core's parent) and of Python's and
    numpy's versions."""
    import numpy as np

    h = hashlib.sha256()
    h.update(f"python {sys.version_info[0]}.{sys.version_info[1]}; numpy {np.__version__}\n".encode())
    root = PACKAGE_DIR.parent
    for rel in sorted(files):
        h.update(rel.encode() + b"\n")
        h.update((root / rel).read_bytes())
    return h.hexdigest()


def digest_words(hex_digest: str) -> tuple[int, ...]:
    """The digest as signed 64-bit integers (what a compiled function can return)."""
    out = []
    for k in range(DIGEST_WORDS):
        u = int(hex_digest[16 * k:16 * (k + 1)], 16)
        out.append(u - (1 << 64) if u >= (1 << 63) else u)
    return tuple(out)


# ------------------------------------------------------------------------------------------ argument checks

def make_checker(spec):
    """A predicate for one argument, from its JSON description (aot_build.describe_type): True when numba
    would type the value exactly as the compiled signature says."""
    import numpy as np

    kind = spec["k"]
    if kind == "array":
        dtype, ndim, contiguous = np.dtype(spec["dtype"]), spec["ndim"], spec["layout"] == "C"

        def check(v):
            return (type(v) is np.ndarray and v.dtype == dtype and v.ndim == ndim and v.flags.aligned
                    and (not contiguous or v.flags.c_contiguous))
        return check
    if kind == "int64":
        return lambda v: (type(v) is int and -(1 << 63) <= v < (1 << 63)) or type(v) is np.int64
    if kind == "float64":
        return lambda v: type(v) is float or type(v) is np.float64
    if kind == "bool":
        return lambda v: type(v) is bool or type(v) is np.bool_
    if kind in ("tuple", "namedtuple"):
        items = [make_checker(s) for s in spec["items"]]
        n = len(items)
        cls = spec.get("cls")

        def check(v):
            if kind == "tuple":
                if type(v) is not tuple:
                    return False
            elif f"{type(v).__module__}.{type(v).__qualname__}" != cls:
                return False
            if len(v) != n:
                return False
            for c, x in zip(items, v):
                if not c(x):
                    return False
            return True
        return check
    raise ValueError(f"{AOT_SPEC_PATH.name}: unknown argument kind {kind!r}")


def _args_checker(specs):
    checks = [make_checker(s) for s in specs]
    n = len(checks)

    def check(args):
        if len(args) != n:
            return False
        for c, a in zip(checks, args):
            if not c(a):
                return False
        return True
    return check


# ------------------------------------------------------------------------------------------ loading

def load_aot(respect_env: bool = True) -> tuple[dict | None, str]:
    """The compiled variants by kernel name, or None and why not."""
    if respect_env and os.environ.get(ENV_VAR) == "0":
        return None, f"{ENV_VAR}=0"
    if not AOT_SPEC_PATH.is_file():
        return None, f"{AOT_SPEC_PATH.name} not built (`python -m georef_core.gnss.aot_build`)"
    try:
        spec = json.loads(AOT_SPEC_PATH.read_text(encoding="utf-8"))
        digest = source_digest(spec["files"])
    except (OSError, ValueError, KeyError) as exc:
        return None, f"{AOT_SPEC_PATH.name} unreadable: {exc}"
    if digest != spec.get("source_sha256"):
        return None, "the kernels' source changed since the ahead-of-time module was built"
    try:
        from ..cli.numba_start import preload_lapack_tables

        preload_lapack_tables()   # the compiled np.linalg calls look up scipy's LAPACK tables by module name
        module = importlib.import_module(AOT_MODULE)
        if tuple(module.source_digest_words()) != digest_words(digest):
            return None, f"{AOT_MODULE} was not built from the source {AOT_SPEC_PATH.name} describes"
        variants: dict[str, list] = {}
        for e in spec["exports"]:
            variants.setdefault(e["kernel"], []).append((getattr(module, e["name"]), _args_checker(e["args"]),
                                                         e["name"]))
    except Exception as exc:   # noqa: BLE001 - any failure: numba's path, as before
        return None, f"{AOT_MODULE} not usable: {type(exc).__name__}: {exc}"
    return variants, ""


def _decide() -> str:
    if _state["mode"] is None:
        variants, why = (load_aot() if _state["want_aot"] else (None, "not requested"))
        _state["mode"] = "aot" if variants is not None else "jit"
        _state["variants"] = variants or {}
        _state["why"] = why
    return _state["mode"]


def prefer_aot() -> bool:
    """Use the ahead-of-time kernels in this process if they are present and current. Call before the
    kernel modules are imported; True when the kernels will run ahead-of-time compiled code. A test process
    (pytest) keeps numba's kernels unless GEOREF_GNSS_AOT=1: its other tests inspect the dispatchers."""
    if "pytest" in sys.modules and os.environ.get(ENV_VAR) != "1":
        return _state["mode"] == "aot"
    if _state["mode"] is None:
        _state["want_aot"] = os.environ.get(ENV_VAR) != "0"
    return _decide() == "aot"


def status() -> dict:
    """mode ("aot" | "jit" | None: no kernel decorated yet), why not aot, and the compiled kernels."""
    return {"mode": _state["mode"], "why": _state["why"], "kernels": sorted(_state["variants"])}


# ------------------------------------------------------------------------------------------ the decorator

class AotKernel:
    """A kernel in a process that uses the ahead-of-time module: calls a compiled variant whose argument
    types match, else (or once the process has switched) numba's dispatcher of the same function."""

    def __init__(self, py_func, options: dict, variants: list):
        self.py_func = py_func
        self.options = options
        self.variants = variants
        self.dispatcher = None
        functools.update_wrapper(self, py_func)

    def __call__(self, *args, **kwargs):
        if self.dispatcher is None and not kwargs:
            for fn, check, _ in self.variants:
                if check(args):
                    return fn(*args)
        if self.dispatcher is None:
            switch_to_jit(f"{self.__module__}.{self.__qualname__}: no ahead-of-time variant for these arguments"
                          if self.variants else f"{self.__module__}.{self.__qualname__}: not compiled ahead of time")
        return self.dispatcher(*args, **kwargs)

    def __repr__(self):
        return f"<AotKernel {self.__module__}.{self.__qualname__} ({len(self.variants)} compiled variant(s))>"


def switch_to_jit(why: str) -> None:
    """From now on this process uses numba: every kernel gets its dispatcher (its module's globals point at
    the dispatchers, so that numba compiles callers against callees), later kernels are numba's."""
    if _state["mode"] == "jit" and all(w.dispatcher is not None for w in _wrappers):
        return
    try:
        from ..cli.numba_start import trim_numba_start

        trim_numba_start()
    except Exception:   # noqa: BLE001 - only a start-up trim
        pass
    import numba

    _state["mode"], _state["why"] = "jit", why
    for w in _wrappers:
        if w.dispatcher is None:
            w.dispatcher = numba.njit(**w.options)(w.py_func)
    by_id = {id(w): w.dispatcher for w in _wrappers}
    for name in {w.py_func.__module__ for w in _wrappers}:
        module = sys.modules.get(name)
        if module is None:
            continue
        for attr, value in list(vars(module).items()):
            if isinstance(value, AotKernel) and id(value) in by_id:
                setattr(module, attr, by_id[id(value)])


def njit(*args, **options):
    """``numba.njit`` (``@njit`` or ``@njit(cache=True, ...)``), or the ahead-of-time wrapper (module doc)."""
    if args and callable(args[0]) and not options and len(args) == 1:
        return njit()(args[0])
    if args:
        raise TypeError("kernel_loader.njit takes keyword options only")
    if _decide() == "jit":
        import numba

        return numba.njit(**options)

    def decorate(py_func):
        name = f"{py_func.__module__}.{py_func.__qualname__}"
        w = AotKernel(py_func, dict(options), _state["variants"].get(name, []))
        if _state["mode"] == "jit":   # switched while the module was being imported
            import numba

            w.dispatcher = numba.njit(**options)(py_func)
            return w.dispatcher
        _wrappers.append(w)
        return w
    return decorate
