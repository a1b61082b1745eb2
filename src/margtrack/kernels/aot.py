"""Ahead-of-time builds of kernels, so a short command starts without importing numba.

A new process that calls a numba kernel pays about half a second before the first sample
(numba's import, its typing registries and its cache lookup), even with every kernel in
numba's cache. An ahead-of-time build is a small extension module compiled by numba's
``pycc`` from the same kernel functions, for the argument types a command was seen to use;
loading it takes milliseconds and needs only numpy.

- :func:`recording` notes which kernels a command ran through numba, with their types;
  :func:`build` compiles those into one module in the cache folder
  (``$MARGTRACK_CACHE_DIR``, else ``$XDG_CACHE_HOME/margtrack``, else ``~/.cache/margtrack``;
  subfolder ``aot``), beside a ``manifest.json`` that names each export, its argument
  types and what it was built from (the kernel sources' sha256, Python, numpy, numba, CPU).
- :func:`find` serves a kernel call from a build when the build is current (same sources,
  versions and CPU) and every argument has the recorded type (dtype, dimensions, memory
  layout, writeable); anything else goes to numba as usual (:mod:`margtrack.kernels.jit`).

``MARGTRACK_AOT=0`` switches it off; numba's ``NUMBA_DISABLE_JIT`` does too. Results equal
numba's: the same code, compiled by the same LLVM for this CPU.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.util
import json
import os
import platform
import shutil
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from margtrack.kernels import jit

__all__ = [
    "Recorded", "build", "cache_dir", "enabled", "find", "recording", "remember_failure",
    "worth_building",
]

#: manifest format of a build folder
MANIFEST_VERSION = 1
_PACKAGE_ROOT = Path(__file__).resolve().parents[1]

ArgSpec = tuple[Any, ...]
#: a build made from other sources or versions is removed once it is this old (s)
STALE_AFTER_S = 86_400.0
#: file in the cache folder noting a failed build (with the versions it failed with)
_FAILED = "failed.json"


def enabled() -> bool:
    """Whether ahead-of-time builds are used and made (``MARGTRACK_AOT``, ``NUMBA_DISABLE_JIT``)."""
    if os.environ.get("MARGTRACK_AOT", "1").strip().lower() in ("0", "false", "no", "off"):
        return False
    return os.environ.get("NUMBA_DISABLE_JIT", "0") in ("", "0")


def cache_dir() -> Path:
    """The folder of ahead-of-time builds."""
    root = os.environ.get("MARGTRACK_CACHE_DIR")
    if root:
        return Path(root) / "aot"
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg) if xdg else Path.home() / ".cache"
    return base / "margtrack" / "aot"


def arg_spec(value: Any) -> ArgSpec | None:
    """The type of one argument as a build records it; None for a type builds never take."""
    if isinstance(value, np.ndarray):
        flags = value.flags
        layout = "C" if flags.c_contiguous else "F" if flags.f_contiguous else "A"
        return ("array", value.dtype.name, value.ndim, layout, not flags.writeable)
    if isinstance(value, bool | np.bool_):
        return ("bool",)
    if isinstance(value, int):
        return ("int64",) if -(2**63) <= value < 2**63 else None
    if isinstance(value, float):
        return ("float64",)
    if isinstance(value, np.generic):
        return (value.dtype.name,)
    return None


def _accepts(wanted: ArgSpec, given: ArgSpec | None) -> bool:
    """Whether an argument of type ``given`` may be passed where ``wanted`` was compiled."""
    if given is None or wanted[0] != given[0]:
        return False
    if wanted[0] != "array":
        return wanted == given
    _, dtype, ndim, layout, readonly = wanted
    if (dtype, ndim) != (given[1], given[2]):
        return False
    if layout != "A" and given[3] != layout:
        return False
    return readonly or not given[4]


def _numba_spec(numba_type: Any) -> ArgSpec | None:
    """A numba argument type as an :func:`arg_spec` (None: not one builds take)."""
    from numba.core import types

    if isinstance(numba_type, types.Array):
        return ("array", np.dtype(str(numba_type.dtype)).name, numba_type.ndim,
                numba_type.layout, not numba_type.mutable)
    if isinstance(numba_type, types.Boolean):
        return ("bool",)
    if isinstance(numba_type, types.Integer | types.Float):
        return (str(numba_type),)
    return None


# ---------------------------------------------------------------- what a build was made from


def _cpu() -> str:
    """This CPU, as far as builds for ``host`` depend on it."""
    with contextlib.suppress(OSError), open("/proc/cpuinfo", encoding="utf-8") as f:
        for line in f:
            if line.startswith("model name"):
                return hashlib.sha256(line.encode()).hexdigest()[:16] + platform.machine()
    return f"{platform.machine()} {platform.processor()}"  # no /proc (macOS, Windows)


def _numba_version() -> str:
    """numba's installed version, read without importing numba (that is the point here)."""
    spec = importlib.util.find_spec("numba")
    if spec is None or not spec.submodule_search_locations:
        return "absent"
    version_file = Path(next(iter(spec.submodule_search_locations))) / "_version.py"
    try:
        return hashlib.sha256(version_file.read_bytes()).hexdigest()[:16]
    except OSError:
        return "unknown"


def _versions() -> dict[str, str]:
    return {
        "python": platform.python_version(),
        "numpy": np.__version__,
        "numba": _numba_version(),
        "cpu": _cpu(),
    }


def _source_hashes(modules: set[str]) -> dict[str, str]:
    hashes = {}
    for name in sorted(modules):
        module = sys.modules.get(name)
        path = Path(getattr(module, "__file__", "") or "")
        if path.is_file():
            hashes[_relative(path)] = hashlib.sha256(path.read_bytes()).hexdigest()
    return hashes


def _relative(path: Path) -> str:
    try:
        return str(path.resolve().relative_to(_PACKAGE_ROOT))
    except ValueError:
        return str(path.resolve())


def _current(manifest: dict[str, Any], versions: dict[str, str]) -> bool:
    """Whether a build was made from these versions and today's kernel sources."""
    if manifest.get("format") != MANIFEST_VERSION or manifest.get("versions") != versions:
        return False
    for rel, digest in manifest.get("sources", {}).items():
        path = Path(rel) if Path(rel).is_absolute() else _PACKAGE_ROOT / rel
        try:
            if hashlib.sha256(path.read_bytes()).hexdigest() != digest:
                return False
        except OSError:
            return False
    return True


# ---------------------------------------------------------------- finding a build's function


@dataclass
class _Export:
    folder: Path
    module: str
    name: str
    args: tuple[ArgSpec, ...]
    function: Callable[..., Any] | None = None


@dataclass
class _Index:
    by_kernel: dict[str, list[_Export]] = field(default_factory=dict)


_INDEX: _Index | None = None


def _manifests() -> Iterator[tuple[Path, dict[str, Any]]]:
    try:
        root = cache_dir()
        if not root.is_dir():
            return
    except (OSError, RuntimeError, KeyError):  # no home folder: no builds, numba as usual
        return
    for folder in sorted(root.iterdir()):
        try:
            yield folder, json.loads((folder / "manifest.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue


def _load_index() -> _Index:
    index = _Index()
    manifests = list(_manifests())
    if not manifests:
        return index
    versions = _versions()
    for folder, manifest in manifests:
        if not _current(manifest, versions):
            continue
        for export in manifest.get("exports", []):
            args = tuple(tuple(a) for a in export["args"])
            entry = _Export(folder, manifest["module"], export["name"], args)
            index.by_kernel.setdefault(export["kernel"], []).append(entry)
    return index


def _function(export: _Export) -> Callable[..., Any] | None:
    if export.function is None:
        module = sys.modules.get(export.module)
        if module is None:
            paths = sorted(export.folder.glob(f"{export.module}*.so")) + sorted(
                export.folder.glob(f"{export.module}*.pyd"))
            if not paths:
                return None
            spec = importlib.util.spec_from_file_location(export.module, paths[0])
            if spec is None or spec.loader is None:
                return None
            module = importlib.util.module_from_spec(spec)
            try:
                spec.loader.exec_module(module)
            except ImportError:
                return None
            sys.modules[export.module] = module
        export.function = getattr(module, export.name, None)
    return export.function


def find(kernel: jit.LazyKernel, args: tuple[Any, ...]) -> Callable[..., Any] | None:
    """The ahead-of-time function for ``kernel`` called with ``args``, or None."""
    global _INDEX
    if not enabled():
        return None
    if _INDEX is None:
        _INDEX = _load_index()
    exports = _INDEX.by_kernel.get(kernel.key)
    if not exports:
        return None
    given = [arg_spec(a) for a in args]
    for export in exports:
        if len(export.args) == len(given) and all(map(_accepts, export.args, given)):
            return _function(export)
    return None


def forget() -> None:
    """Read the cache folder again on the next call (after a build or a change of folder)."""
    global _INDEX
    _INDEX = None


# ---------------------------------------------------------------- recording and building


@dataclass
class Recorded:
    """Kernel signatures numba loaded or compiled inside :func:`recording` (in that order)."""

    calls: dict[tuple[str, str], tuple[jit.LazyKernel, Any]] = field(default_factory=dict)

    def __bool__(self) -> bool:
        return bool(self.calls)


def _overloads() -> dict[int, set[Any]]:
    return {id(k): set(k.dispatcher.overloads) for k in jit.kernels() if k.dispatcher is not None}


@contextlib.contextmanager
def recording() -> Iterator[Recorded]:
    """Note the kernel signatures numba runs for the first time in this process in the block.

    These are the kernels the block called from Python, plus, on a cold numba cache, the
    kernels those call that numba compiled separately (building those too is harmless).
    Kernels with options beyond ``cache`` and ``nogil`` are left out: a build compiles its
    entry point with pycc's default flags, so a ``fastmath`` entry would not give numba's
    result (a build holds the GIL: callers that need it released call numba's dispatcher,
    ``jit.dispatcher``).
    """
    recorded = Recorded()
    before = _overloads()
    try:
        yield recorded
    finally:
        for kernel in jit.kernels():
            if kernel.dispatcher is None or set(kernel.options) - {"cache", "nogil"}:
                continue
            for argtypes, overload in kernel.dispatcher.overloads.items():
                signature = overload.signature
                if argtypes in before.get(id(kernel), ()) or not all(
                        _numba_spec(t) is not None for t in signature.args):
                    continue
                recorded.calls.setdefault((kernel.key, str(signature)), (kernel, signature))


def build(recorded: Recorded) -> Path | None:
    """Compile the recorded kernels into a new build; its folder, or None when not needed.

    Builds that no longer match the sources or versions are removed (:func:`_prune`).
    Raises what ``pycc`` raises (a missing C compiler, ...); the caller decides how loudly
    to say so.
    """
    if not recorded or not enabled():
        return None
    _prune(_versions())
    todo = _todo(recorded)
    if not todo:
        return None
    versions = _versions()
    import tempfile
    import uuid

    build_id = uuid.uuid4().hex[:12]
    module = f"margtrack_aot_{build_id}"
    root = cache_dir()
    root.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".building-", dir=root))
    try:
        exports = _compile(module, todo, staging)
        manifest = {
            "format": MANIFEST_VERSION,
            "module": module,
            "versions": versions,
            "sources": _source_hashes({k.py_func.__module__ for k in jit.kernels()}),
            "exports": exports,
        }
        (staging / "manifest.json").write_text(json.dumps(manifest, indent=1), encoding="utf-8")
        final = root / build_id
        staging.rename(final)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    forget()
    return final


def _todo(recorded: Recorded) -> list[tuple[jit.LazyKernel, Any]]:
    """The recorded calls no current build serves."""
    forget()
    index = _load_index()
    return [(kernel, sig) for (key, _), (kernel, sig) in recorded.calls.items()
            if not _served(index, key, sig)]


def worth_building(recorded: Recorded) -> bool:
    """Whether :func:`build` would compile something (and has not failed with these versions)."""
    if not recorded or not enabled():
        return False
    try:
        failed = json.loads((cache_dir() / _FAILED).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        failed = None
    if failed is not None and failed.get("versions") == _versions():
        return False
    return bool(_todo(recorded))


def remember_failure(exc: BaseException) -> None:
    """Note that a build failed with these versions, so commands stop trying."""
    root = cache_dir()
    with contextlib.suppress(OSError):
        root.mkdir(parents=True, exist_ok=True)
        note = {"versions": _versions(), "error": f"{type(exc).__name__}: {exc}"}
        (root / _FAILED).write_text(json.dumps(note), encoding="utf-8")


def _served(index: _Index, key: str, signature: Any) -> bool:
    wanted = tuple(_numba_spec(t) for t in signature.args)
    return any(e.args == wanted for e in index.by_kernel.get(key, []))


def _compile(module: str, todo: list[tuple[jit.LazyKernel, Any]], folder: Path) -> list[dict]:
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # pycc is "pending deprecation" in numba 0.57+
        from numba.pycc import CC

    cc = CC(module)
    cc.output_dir = str(folder)
    cc.target_cpu = "host"  # as numba's JIT compiles; the manifest pins the CPU
    cc.verbose = False
    exports = []
    for i, (kernel, signature) in enumerate(todo):
        name = f"k{i}"
        cc.export(name, signature)(kernel.py_func)
        exports.append({"kernel": kernel.key, "name": name,
                        "args": [list(_numba_spec(t)) for t in signature.args]})
    with warnings.catch_warnings(), open(os.devnull, "w") as devnull, \
            contextlib.redirect_stdout(devnull):
        warnings.simplefilter("ignore")
        cc.compile()
    return exports


def _prune(versions: dict[str, str]) -> None:
    """Remove builds made from other sources or versions a day ago or earlier.

    The day's grace keeps two installations sharing the cache folder (a second virtual
    environment, an edited checkout) from removing each other's builds in turn.
    """
    import time

    for folder, manifest in list(_manifests()):
        try:
            age_s = time.time() - (folder / "manifest.json").stat().st_mtime
        except OSError:
            continue
        if age_s > STALE_AFTER_S and not _current(manifest, versions):
            shutil.rmtree(folder, ignore_errors=True)
