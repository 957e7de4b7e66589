"""A short `georef gnss solve` process: what numba loads before the first kernel runs, trimmed.

numba builds its CPU target on the first call of a kernel (cached or not), then loads each cached kernel.
Three parts of that cost a fresh process much and give a GNSS solve nothing (docs/gnss.md, "Whole
process"):

* ``numba.np.arraymath`` checks that BLAS is there by importing ``scipy.linalg.cython_blas``; importing it
  runs ``scipy.linalg``'s package ``__init__`` (the whole Python API of scipy.linalg, whose array-API
  shim imports ``numpy.f2py`` and ``numpy.testing``): ~40 % of numba's target set-up. The kernels need only
  the two Cython modules' function tables (``__pyx_capi__``: the LAPACK routines numba's ``np.linalg``
  calls), so :func:`preload_lapack_tables` loads those two extension modules from their files and
  registers them under their names; numba's check and its run-time look-up of the routines then find them
  in ``sys.modules``. The same files, the same routines: results are unchanged.
* numba's typing registries import ``numba.core.typing.cffi_utils``, which builds a ``cffi.FFI()`` and so
  imports pycparser and compiles its lexer's regular expressions (~15 %). No kernel takes a cffi object:
  :func:`skip_cffi_typing` imports that module while ``cffi`` cannot be imported (numba then records
  cffi support as absent), and makes ``cffi`` importable again at once.
* numba broadcasts an event ("numba:llvm_lock") around every call into llvmlite, to record in a compiled
  function's metadata how long it held the LLVM lock. Loading the cached kernels makes ~10 000 such calls
  (reading back each library's symbols), and the two Python callbacks per call are ~20 % of the loading
  time: :func:`skip_llvm_lock_events` unregisters numba's own pair (the lock itself stays; a compilation in
  this process would only miss that timing in its metadata).

All three are for a process that runs the solve and ends (the CLI); each does nothing when its part is
already loaded, and a failure leaves numba to load things its own way.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import sys
from pathlib import Path

LAPACK_TABLES = ("scipy.linalg.cython_blas", "scipy.linalg.cython_lapack")


def preload_lapack_tables() -> bool:
    """Load scipy's Cython BLAS/LAPACK function tables without ``scipy.linalg``'s package ``__init__``.
    True when both are now in ``sys.modules`` and scipy.linalg itself is not loaded."""
    if "scipy.linalg" in sys.modules:
        return False
    try:
        spec = importlib.util.find_spec("scipy")
        if spec is None or not spec.submodule_search_locations:
            return False
        import scipy  # noqa: F401  (the top-level package, light: what numba's own import loads first)

        linalg_dir = Path(next(iter(spec.submodule_search_locations))) / "linalg"
        loaded = {}
        for full in LAPACK_TABLES:
            if full in sys.modules:
                continue
            stem = full.rsplit(".", 1)[1]
            path = next((linalg_dir / (stem + s) for s in importlib.machinery.EXTENSION_SUFFIXES
                         if (linalg_dir / (stem + s)).is_file()), None)
            if path is None:
                return False
            loader = importlib.machinery.ExtensionFileLoader(full, str(path))
            mspec = importlib.util.spec_from_file_location(full, path, loader=loader)
            module = importlib.util.module_from_spec(mspec)
            loader.exec_module(module)
            if not getattr(module, "__pyx_capi__", None):
                return False
            loaded[full] = module
        sys.modules.update(loaded)
        return "scipy.linalg" not in sys.modules
    except Exception:   # any surprise: numba imports scipy.linalg itself, as before
        return False


def skip_cffi_typing() -> bool:
    """Import numba's cffi typing support while cffi cannot be imported (numba: cffi support absent),
    then let cffi be imported again. True when numba's cffi typing was set up without cffi."""
    name = "numba.core.typing.cffi_utils"
    if name in sys.modules or "cffi" in sys.modules:
        return False
    sys.modules["cffi"] = None   # `import cffi` raises ImportError while this is here
    try:
        importlib.import_module(name)
        return not sys.modules[name].SUPPORTED
    except Exception:
        sys.modules.pop(name, None)
        return False
    finally:
        if "cffi" in sys.modules and sys.modules["cffi"] is None:
            del sys.modules["cffi"]


def skip_llvm_lock_events() -> bool:
    """Unregister numba's LLVM-lock event callbacks (numba.core.base registers them when imported). True
    when a pair was removed."""
    try:
        import numba.core.base  # noqa: F401  (registers the callbacks, if not yet imported)
        from llvmlite.binding import ffi

        lock = ffi.lib._lock
        numba_pairs = [pair for pair in list(lock._cblist)
                       if getattr(pair[0], "__qualname__", "").startswith("_initialize_llvm_lock_event.")]
        for pair in numba_pairs:
            lock.unregister(*pair)
        return bool(numba_pairs)
    except Exception:   # another llvmlite: leave the callbacks
        return False


def trim_numba_start() -> dict:
    """All of the above; what each did (for the benchmark's breakdown)."""
    return {"lapack_tables": preload_lapack_tables(), "cffi_typing": skip_cffi_typing(),
            "llvm_lock_events": skip_llvm_lock_events()}
