"""The package's one owner of numba: the switch, the kernel decorator, the disk cache.

* :data:`ENABLED` is the one switch of every compiled kernel (``HQP_TPM_COMPILED=0`` at import: off; may be set
  in a running process; ``hqp_tpm.solvers._compiled.ENABLED`` and ``hqp_tpm.robot._compiled.ENABLED`` are the same
  switch, :func:`share_switch`). Off, the readable paths run; :data:`AVAILABLE`: numba can be found.
* :func:`kernel` marks a function of a kernel module; :func:`compile_module` replaces the module's marked functions
  by numba dispatchers (``nogil``, cached; numba compiles each on its first call, or loads it from the cache), and
  :func:`compile_when_enabled` does so now if the switch is on, else when it is turned on (off from the start,
  numba is never imported). Until then, and without numba, they are the plain Python functions.
* The disk cache lives in a directory named by a hash of the source of every kernel module and the modules they
  import from the package (:func:`source_key`): numba checks a cached function against its own file only, but a
  compiled kernel holds the code of the kernels it calls and the constants it reads, so any change to those files
  starts a fresh directory (no stale callee is ever loaded; the directory is numba's documented
  ``NUMBA_CACHE_DIR`` / ``numba.config.CACHE_DIR``, set while the package's dispatchers are made and restored
  after). Its root is the first writable of ``$NUMBA_CACHE_DIR/hqp_tpm``, the package's ``__pycache__`` and the
  user cache directory (``$XDG_CACHE_HOME`` or ``~/.cache``, ``/hqp_tpm``); with none writable (a read-only install
  run by a user without a home) the kernels compile in memory, once per process, with a one-line notice on stderr.
  The four most recently used directories (and any used in the last hour) are kept. A kernel found there is loaded
  by :func:`kernel_cache`'s subclass of numba's cache class, which skips the refresh of numba's compiler registries
  that loading machine code does not need (the package's dispatchers only; numba's compiler refreshes them itself
  whenever it compiles).
* Before numba reads the cache, every cache file (index ``.nbi``, data ``.nbc``) not seen whole before is parsed
  as the pickle stream numba reads (:mod:`pickletools`, nothing is executed); a damaged one (truncated, zeroed) is
  deleted with a one-line notice on stderr, and numba compiles that kernel again and writes it anew. Files seen
  whole are listed with their size and modification time (``checked.txt``), so a later process only stats them.
* When numba compiles a kernel of the package (not when it loads one from the cache) a one-line notice says so on
  stderr, once per process (:data:`COMPILING`; none when a notice above already said why they compile), through
  :func:`set_notice_writer`'s writer (e.g. a progress bar's); :func:`compile_seconds` is the time the process
  spent compiling kernels or loading them from the cache, so callers can keep it out of step times.
* numba is imported, and compiles or loads, with the cyclic garbage collector paused (:func:`gc_paused`); the
  objects alive after numba's first import are frozen (``gc.freeze()``, :func:`_numba`), and so are those alive
  after each compile's collection (what numba keeps of a compile): later collections and the interpreter's at exit
  do not walk numba's registries again. With these a process that loads its kernels from the
  cache spends ~0.1 s of CPU on them (a 1,000-step script is no slower than with ``HQP_TPM_COMPILED=0``;
  ``benchmarks/first_run.py``).
"""

from __future__ import annotations

import contextlib
import gc
import hashlib
import importlib.util
import io
import math
import os
import pickletools
import re
import shutil
import sys
import tempfile
import threading
import time
import types
from pathlib import Path

_SWITCH = {"available": importlib.util.find_spec("numba") is not None}
_SWITCH["enabled"] = _SWITCH["available"] and \
    os.environ.get("HQP_TPM_COMPILED", "1").strip().lower() not in ("0", "false", "no", "off")

PACKAGE = Path(__file__).resolve().parent
#: Cache directories kept under a root (the current one and the most recent others).
KEEP = 4
#: The list of cache files found whole (name, size, modification time), in the cache directory.
CHECKED = "checked.txt"

_KERNELS: dict[str, list[tuple[str, bool]]] = {}   # module -> (name, inline) of its kernels, in order
_COMPILED: set[str] = set()
_PENDING: dict[str, dict] = {}                      # modules compiled when the switch is turned on
_LOCK = threading.RLock()
_CACHE: list = []                                   # [the cache directory or None], once known
_KERNEL_CACHE: list = []                            # [kernel_cache()'s class or None], once known
_NOTICE = [None]                                    # [a writer of notice lines, or None: stderr]
#: The notice printed the first time in a process numba compiles a kernel of the package (not when it loads one).
COMPILING = "compiling kernels: first run on this machine only"
_COMPILE = {"seconds": 0.0, "depth": 0, "start": 0.0, "noticed": False, "listening": False, "gc": True,
            "frozen": False, "compiled": False}
_IMPORTS_JIT = re.compile(r"^\s*(?:from\s+hqp_tpm\s+import\s+[^\n]*\b_jit\b|from\s+hqp_tpm\._jit\s+import|"
                          r"import\s+hqp_tpm\._jit)", re.M)
_FROM_IMPORT = re.compile(r"^\s*from\s+(hqp_tpm(?:\.\w+)*)\s+import\s+(\([^)]*\)|[^\n]*)", re.M)


def notice(message: str) -> None:
    """One line on stderr (or to the writer of :func:`set_notice_writer`)."""
    line = "hqp_tpm: " + " ".join(message.split())
    if _NOTICE[0] is not None:
        _NOTICE[0](line)
        return
    sys.stderr.write(line + "\n")
    sys.stderr.flush()


def set_notice_writer(write=None):
    """Send :func:`notice` lines to ``write(line)`` (None: stderr, the default); returns the previous writer (a
    progress bar on stderr passes its own, which clears the bar, writes the line and draws the bar again)."""
    previous, _NOTICE[0] = _NOTICE[0], write
    return previous


def compile_seconds() -> float:
    """Seconds (wall clock) this process has spent in numba making its kernels: compiling them or loading them
    from the cache (the time numba holds its compiler lock, numba's ``numba:compiler_lock`` events); 0.0 before
    any."""
    return _COMPILE["seconds"] + (time.perf_counter() - _COMPILE["start"] if _COMPILE["depth"] else 0.0)


def _listen() -> None:
    """Register the listeners of numba's events (once): the first compile of a package kernel in the process (a
    ``numba:compile`` event, which loading from the cache does not raise) prints :data:`COMPILING`; the outermost
    ``numba:compiler_lock`` spans add up to :func:`compile_seconds`."""
    if _COMPILE["listening"]:
        return
    from numba.core import event

    class Compiling(event.Listener):
        def on_start(self, ev):
            _COMPILE["compiled"] = True
            fn = getattr(ev.data.get("dispatcher"), "py_func", None)
            in_memory = bool(_CACHE) and _CACHE[0] is None  # (compiled in every process: cache_dir's notice says so)
            if not _COMPILE["noticed"] and not in_memory and getattr(fn, "__module__", "").startswith("hqp_tpm"):
                _COMPILE["noticed"] = True
                notice(COMPILING)

        def on_end(self, ev):
            pass

    class Locked(event.Listener):
        def on_start(self, ev):
            if _COMPILE["depth"] == 0:
                _COMPILE["start"] = time.perf_counter()
                _COMPILE["gc"] = gc.isenabled()
                gc.disable()
            _COMPILE["depth"] += 1

        def on_end(self, ev):
            _COMPILE["depth"] = max(_COMPILE["depth"] - 1, 0)
            if _COMPILE["depth"] == 0:
                if _COMPILE["gc"]:  # the span's objects collected once, here: not in the caller's next steps
                    gc.enable()
                    gc.collect(2 if _COMPILE["compiled"] else 0)
                    if _COMPILE["compiled"]:  # what numba keeps of a compile (its IR, types, code) lives as long
                        gc.freeze()           # as the process: later collections do not walk it again (_numba)
                _COMPILE["compiled"] = False
                _COMPILE["seconds"] += time.perf_counter() - _COMPILE["start"]

    event.register("numba:compile", Compiling())
    event.register("numba:compiler_lock", Locked())
    _COMPILE["listening"] = True


def kernel(fn=None, *, inline: bool = False, into: tuple[str, str] | None = None):
    """Mark ``fn`` as a kernel of its module (plain Python until :func:`compile_module`). ``inline=True``: numba
    inlines it where compiled code calls it (its IR, before LLVM: the same operations in the same order). ``into =
    (module, name)``: a function of another module compiled as the global ``name`` of ``module`` (its own stays
    Python)."""
    def mark(f):
        module, name = into or (f.__module__, f.__name__)
        _KERNELS.setdefault(module, []).append((name, inline))
        return f
    return mark if fn is None else mark(fn)


def compile_module(namespace: dict) -> bool:
    """Replace the kernels of the module whose globals are ``namespace`` by numba dispatchers (once; numba compiles
    each on its first call, or loads it from the cache). False (nothing replaced) if numba cannot be imported: then
    :data:`ENABLED` and :data:`AVAILABLE` become False."""
    name = namespace["__name__"]
    with _LOCK:
        if name in _COMPILED:
            return True
        if not _SWITCH["available"]:
            return False
        made = {}
        for fn_name, inline in _KERNELS.get(name, ()):
            made[fn_name] = dispatcher(namespace[fn_name], inline=inline)
            if made[fn_name] is None:
                return False
        namespace.update(made)
        _COMPILED.add(name)
        _PENDING.pop(name, None)
        return True


def compile_when_enabled(namespace: dict) -> None:
    """:func:`compile_module` now if :data:`ENABLED`, else when the switch is turned on."""
    if _SWITCH["enabled"]:
        compile_module(namespace)
    else:
        _PENDING[namespace["__name__"]] = namespace


def set_enabled(value: bool) -> None:
    """Turn the switch (on: only if numba can be imported; the modules waiting for it are compiled)."""
    with _LOCK:
        _SWITCH["enabled"] = bool(value) and _SWITCH["available"]
        if _SWITCH["enabled"]:
            for namespace in list(_PENDING.values()):
                compile_module(namespace)


def _numba():
    """numba, imported with the cyclic garbage collector paused (:func:`gc_paused`); the first time, every object
    alive then is moved to the collector's permanent generation (``gc.freeze()``): numba's import makes tens of
    thousands of objects that live as long as the process, and each full collection after (and the interpreter's at
    exit) would walk them all again (~0.13 s of CPU in a 1,000-step script, ``benchmarks/first_run.py``). What is
    frozen is what the imports so far made (modules, numba's registries) and is never freed before exit anyway."""
    with gc_paused():
        import numba
    if not _COMPILE["frozen"]:
        _COMPILE["frozen"] = True
        gc.freeze()
    return numba


@contextlib.contextmanager
def gc_paused():
    """The cyclic garbage collector off inside (as it was after): importing numba, and numba compiling or loading a
    kernel (the listener of ``numba:compiler_lock`` does the same), make hundreds of thousands of objects that live as
    long as the process; each collection meanwhile walks them all again (15 % of a first run's CPU, a third of a warm
    process's kernel load). Nothing is computed differently; the garbage of those spans is collected after."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def kernel_cache():
    """The class of the package's kernels' disk cache (or None: numba's own), a subclass of numba's
    ``FunctionCache`` whose ``load_overload`` loads a kernel without numba's ``target_context.refresh()`` first: that
    refresh imports and registers the typing and lowering of everything numba can compile (numpy, linalg, typed
    containers, random, ...; ~0.25 s of CPU, then more at exit), which compiling needs (numba's compiler refreshes
    the context itself, whatever the cache did) but loading machine code does not: it needs numba's runtime (NRT),
    initialized here as numba's refresh does first. The loaded code is the code numba compiled and wrote, the same
    bits. Should the load meet anything else (another numba), the full refresh runs and numba loads it its way."""
    if not _KERNEL_CACHE:
        cls = None
        try:
            from numba.core.caching import FunctionCache
            from numba.core.runtime import rtsys

            if all(hasattr(FunctionCache, a) for a in ("_guard_against_spurious_io_errors", "_load_overload")) \
                    and hasattr(rtsys, "initialize"):
                class KernelCache(FunctionCache):
                    """numba's cache of one kernel, loaded without refreshing numba's compiler registries."""

                    def load_overload(self, sig, target_context):
                        try:
                            rtsys.initialize(target_context)
                            with self._guard_against_spurious_io_errors():
                                return self._load_overload(sig, target_context)
                        except Exception:  # noqa: BLE001 - numba's own way then
                            return super().load_overload(sig, target_context)

                cls = KernelCache
        except ImportError:  # pragma: no cover - another numba: its own cache class
            cls = None
        _KERNEL_CACHE.append(cls)
    return _KERNEL_CACHE[0]


def dispatcher(fn, inline: bool = False):
    """``fn`` as a numba dispatcher (``nogil``; cached in :func:`cache_dir` when there is one, loaded by
    :func:`kernel_cache`'s class, else compiled in memory), or None if numba cannot be imported."""
    with _LOCK:
        try:
            numba = _numba()
        except ImportError as e:  # found but broken (e.g. llvmlite): the readable paths from now on
            _SWITCH["available"] = _SWITCH["enabled"] = False
            notice(f"numba cannot be imported ({e}): the compiled kernels are off")
            return None
        _listen()
        where = cache_dir()
        # no_cfunc_wrapper: no C-callable wrapper (for a kernel passed as a first-class function value, which the
        # package never does) compiled and optimized beside each kernel: ~5 % of a kernel's compile
        options = {"nogil": True, "inline": "always" if inline else "never", "no_cfunc_wrapper": True}
        d = numba.njit(**options)(fn)
        if where is None:
            return d
        before = numba.config.CACHE_DIR
        numba.config.CACHE_DIR = str(where)  # read once, by the dispatcher's cache locator (restored below)
        try:
            cache = kernel_cache()
            if cache is None:
                d.enable_caching()  # (numba's njit(cache=True))
            else:
                d._cache = cache(d.py_func)  # (what enable_caching sets, with this cache class)
        except RuntimeError:  # no cache locator after all (the directory went away): in memory
            pass
        finally:
            numba.config.CACHE_DIR = before
        return d


def lapack_gesdd():
    """numba's driver of LAPACK's ``dgesdd`` (``numba_ez_gesdd``: what numba's ``np.linalg.svd`` calls, the
    workspace query and then ``dgesdd``), a function compiled code can call; None if this numba (or scipy) has none.
    """
    try:
        numba = _numba()
        from numba.np import linalg

        linalg.ensure_lapack()
        return linalg._LAPACK().numba_ez_gesdd(numba.types.float64)
    except Exception:  # noqa: BLE001 - another numba or no scipy: numba's np.linalg.svd
        return None


def share_switch(module_name: str) -> None:
    """Make ``ENABLED`` and ``AVAILABLE`` of module ``module_name`` read and write this module's (one switch for
    every module that has a switch of its own name; this module's own are made so at its end)."""
    module = sys.modules[module_name]
    for attr in ("ENABLED", "AVAILABLE"):
        module.__dict__.pop(attr, None)
    module.__class__ = _SharedSwitch


class _SharedSwitch(types.ModuleType):
    """A module whose ``ENABLED`` and ``AVAILABLE`` are :mod:`hqp_tpm._jit`'s."""

    @property
    def ENABLED(self) -> bool:  # noqa: N802 - the module attribute's name
        return _SWITCH["enabled"]

    @ENABLED.setter
    def ENABLED(self, value) -> None:  # noqa: N802
        set_enabled(value)

    @property
    def AVAILABLE(self) -> bool:  # noqa: N802
        return _SWITCH["available"]

    @AVAILABLE.setter
    def AVAILABLE(self, value) -> None:  # noqa: N802
        _SWITCH["available"] = bool(value)


# -- the cache ---------------------------------------------------------------------------------------------------
def kernel_files() -> list[Path]:
    """The package's files whose content a compiled kernel depends on: this file, every module that imports it and
    the package modules those import by name (their constants are compiled in); the application layer (``app/``,
    which imports this module for :func:`compile_seconds` and :func:`set_notice_writer`) holds no kernel."""
    files = {Path(__file__).resolve()}
    for folder, _, names in os.walk(PACKAGE):
        if Path(folder).relative_to(PACKAGE).parts[:1] == ("app",):  # the application reads the compile clock only
            continue
        for name in names:
            if not name.endswith(".py"):
                continue
            path = Path(folder, name)
            text = path.read_text(encoding="utf-8", errors="replace")
            if "_jit" not in text or not _IMPORTS_JIT.search(text):
                continue
            files.add(path)
            for base, imported in _FROM_IMPORT.findall(text):  # from X import a, b: X.py, else X/a.py or X/__init__
                stem = PACKAGE.parent.joinpath(*base.split("."))
                if stem.with_suffix(".py").is_file():
                    files.add(stem.with_suffix(".py"))
                    continue
                for n in re.findall(r"\w+", re.sub(r"#[^\n]*|\bas\s+\w+", "", imported)):
                    files.add(stem / f"{n}.py" if (stem / f"{n}.py").is_file() else stem / "__init__.py")
    return sorted(f for f in files if f.is_file())


def source_key() -> str:
    """Hash of the numba version, the Python version and the content of :func:`kernel_files` (16 hex digits)."""
    numba = _numba()

    h = hashlib.sha256(f"{numba.__version__} {sys.version}".encode())
    for path in kernel_files():
        h.update(str(path.relative_to(PACKAGE.parent)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


def _roots() -> list[Path]:
    roots = []
    if os.environ.get("NUMBA_CACHE_DIR"):
        roots.append(Path(os.environ["NUMBA_CACHE_DIR"]) / "hqp_tpm")
    roots.append(PACKAGE / "__pycache__")
    xdg = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    roots.append(Path(xdg) / "hqp_tpm")
    return roots


def _writable(path: Path) -> bool:
    try:
        path.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=path).close()  # (numba's own test of a cache directory)
        return True
    except OSError:
        return False


def cache_dir() -> Path | None:
    """The directory of the compiled kernels' cache (made, pruned and checked on the first call of a process), or
    None: no writable location, the kernels compile in memory."""
    if _CACHE:
        return _CACHE[0]
    with _LOCK:
        if _CACHE:
            return _CACHE[0]
        key, where = f"numba-{source_key()}", None
        for root in _roots():
            if _writable(root / key):
                where = root / key
                break
        if where is None:
            notice("no writable cache directory (tried " + ", ".join(str(r) for r in _roots()) + "): the compiled "
                   "kernels are compiled in memory in each process (set NUMBA_CACHE_DIR to a writable directory)")
        else:
            _prune(where)
            discard_damaged(where)
        _CACHE.append(where)
        return where


def _prune(current: Path) -> None:
    """Mark ``current`` used (its modification time) and delete the cache directories beside it (earlier sources)
    but the most recently used (:data:`KEEP` in all, with ``current``) and those used in the last hour (other
    checkouts sharing the root)."""
    try:
        os.utime(current)
        others = [p for p in current.parent.glob("numba-*") if p != current and p.is_dir()]
        others.sort(key=lambda p: p.stat().st_mtime, reverse=True)
        recent = time.time() - 3600.0
        old = [p for p in others[KEEP - 1:] if p.stat().st_mtime < recent]
    except OSError:
        return
    for p in old:
        shutil.rmtree(p, ignore_errors=True)


def whole(data: bytes, streams: int) -> bool:
    """Do ``data`` hold ``streams`` complete pickle streams, one after the other (parsed, nothing executed)?"""
    f = io.BytesIO(data)
    try:
        for _ in range(streams):
            for _ in pickletools.genops(f):
                pass
    except Exception:  # noqa: BLE001 - whatever the parser meets, the file is not whole
        return False
    return True


def discard_damaged(where: Path) -> list[Path]:
    """Delete the cache files under ``where`` that are not whole pickle streams (an index ``.nbi``: numba's version,
    then its entries; a data file ``.nbc``: one); return them. Those listed in :data:`CHECKED` with their current
    size and modification time are not read again."""
    listing = where / CHECKED
    try:
        seen = set(listing.read_text().splitlines())
    except (OSError, ValueError):  # none yet, or itself damaged: every file is read
        seen = set()
    damaged, checked = [], []
    for path in sorted(where.rglob("*.nb[ic]")):
        try:
            st = path.stat()
            entry = f"{path.relative_to(where)}\t{st.st_size}\t{st.st_mtime_ns}"
            if entry in seen:
                checked.append(entry)
                continue
            if whole(path.read_bytes(), 2 if path.suffix == ".nbi" else 1):
                checked.append(entry)
                continue
            path.unlink()
        except FileNotFoundError:  # (another process replaced or removed it)
            continue
        except OSError:
            continue
        damaged.append(path)
    if damaged:
        _COMPILE["noticed"] = True  # (this notice says they are compiled again: no second line)
        notice(f"discarded {len(damaged)} damaged compiled-kernel cache file(s) in {where} "
               f"({', '.join(p.name for p in damaged[:3])}{', ...' if len(damaged) > 3 else ''}): compiled again")
    if set(checked) != seen:
        try:
            with tempfile.NamedTemporaryFile("w", dir=where, delete=False, suffix=".tmp") as f:
                f.write("\n".join(checked) + "\n")
            os.replace(f.name, listing)
        except OSError:
            pass
    return damaged


# -- arrays read by address (the lean step's program: hqp_tpm.control._compiled_step.Program) -------------------
numba = _float_pointer = None  # set by address_readers (globals of the two kernels below)


@kernel
def table_matrix(ints, slot):  # pragma: no cover - compiled
    """The matrix of slot ``slot`` of an address table in ``ints`` (from ``ints[7]``: address, rows, columns per slot;
    :class:`hqp_tpm.control._compiled_step.Program`, which keeps the arrays alive), a view of that memory."""
    at = ints[7] + 3 * slot
    return numba.carray(_float_pointer(ints[at]), (ints[at + 1], ints[at + 2]))


@kernel
def table_vector(ints, slot):  # pragma: no cover - compiled
    """The vector of slot ``slot`` of the address table from ``ints[8]`` (address, length per slot)."""
    at = ints[8] + 2 * slot
    return numba.carray(_float_pointer(ints[at]), (ints[at + 1],))


# -- a kernel's variant that calls fewer kernels (a first run compiles only what its caller uses) -----------------
@kernel(inline=True)
def _unused_3(a, b, out):  # pragma: no cover - compiled (inlined)
    """Stands in for a kernel of three arguments that a :func:`variant` never calls: NaN into ``out``, its last."""
    for i in range(out.shape[0]):
        out[i] = math.nan


@kernel(inline=True)
def _unused_5(a, b, c, d, out):  # pragma: no cover - compiled (inlined)
    """:func:`_unused_3` of five arguments."""
    for i in range(out.shape[0]):
        out[i] = math.nan


@kernel(inline=True)
def _unused_6(a, b, c, d, e, out):  # pragma: no cover - compiled (inlined)
    """:func:`_unused_3` of six arguments."""
    for i in range(out.shape[0]):
        out[i] = math.nan


def variant(fn, suffix: str, *unused: str, **replaced):
    """A copy of the kernel source ``fn`` (for :func:`dispatcher`) whose globals named ``unused`` (kernels it calls,
    each writing into its last argument, a vector) are stubs that write NaN there: numba compiles none of their
    code, nor the kernels they call. For a caller that never takes the branches calling them (should it after all,
    the NaN fails its finiteness test). ``replaced``: globals read as other kernels (a name to its kernel). The copy
    reads ``fn``'s other globals as they are now, and is named ``fn.__qualname__ + suffix``: numba caches it in files
    of its own. None if numba cannot be imported."""
    if not compile_module(globals()):  # (the stubs as numba dispatchers)
        return None
    stubs = {3: _unused_3, 5: _unused_5, 6: _unused_6}
    names = dict(fn.__globals__)
    for name in unused:
        names[name] = stubs[getattr(names[name], "py_func", names[name]).__code__.co_argcount]
    names.update(replaced)
    copy = types.FunctionType(fn.__code__, names, fn.__name__ + suffix, fn.__defaults__, fn.__closure__)
    copy.__qualname__, copy.__module__, copy.__doc__ = fn.__qualname__ + suffix, fn.__module__, fn.__doc__
    return copy


def address_readers():
    """``(table_matrix, table_vector)`` compiled (numba's ``carray`` on the int64 address made a ``float64*``), or
    None if numba cannot be imported."""
    global numba, _float_pointer
    with _LOCK:
        if _float_pointer is None:
            try:
                nb = _numba()
                from numba.extending import intrinsic
            except ImportError:
                return None

            @intrinsic
            def float_pointer(typingctx, address):
                """The int64 ``address`` as a ``float64*``."""
                def codegen(context, builder, signature, args):
                    return builder.inttoptr(args[0], context.get_value_type(signature.return_type))
                return nb.types.CPointer(nb.types.float64)(nb.types.int64), codegen

            numba, _float_pointer = nb, float_pointer
        if not compile_module(globals()):
            return None
        return table_matrix, table_vector


share_switch(__name__)  # ENABLED, AVAILABLE (module attributes; set_enabled on assignment)
