"""What the teeth modules compiled with numba share: physics written once for numpy and numba, and a
compile cache that notices an edit of any module the compiled tracer is made of.

``numba_callable(fn)``: ``fn`` stays the plain numpy function it is (arrays in, arrays out; it works where
numba is missing) and becomes callable from numba-compiled code as well, which compiles the same source
for its scalar arguments (a ``numba.extending.overload`` whose implementation is ``fn`` itself). So
``fresnel_dielectric``, ``hg`` or ``blend_weight`` exist once, and the numpy reference tracer and the
compiled tracer evaluate one formula. A function written for both uses what numpy and numba agree on
for arrays and scalars alike: arithmetic, ``np.sqrt``, ``np.tanh``, ``np.minimum`` (not ``np.clip`` or
``np.where``, which numba does not take for scalars).

The cache. numba keys a cached function by the hash of its own source file only, yet a compiled function
carries the code of everything it calls or inlines from other modules, and the module-level constants it
read. An edit of ``bvh.py`` therefore used to leave every cached caller in ``path_tracer_compiled`` running
the old traversal. Here every function of the modules in ``KERNEL_MODULES`` gets a source stamp that is the
hash of all those modules' sources together (``kernel_sources_digest``): editing any one of them makes
every cached function of all of them stale, and numba compiles them afresh on the next run. The stamp is that
hash alone, not the files' modification times: the same sources installed again (an extension reinstalled,
a fresh clone) keep their compiled code.

Where the cache lives: beside the sources (numba's ``__pycache__``), or, where the environment variable
``MATERIAL_STRUCTURES_NUMBA_CACHE`` names a folder, in ``<folder>/teeth-<hash>``, which any copy of the same
sources finds wherever it is installed (a test run and the extension zip installed into a bare Blender, machines
of one CPU type sharing a folder). numba keys each compiled function further by its signature, Python
version and CPU, so a cache written elsewhere is only used where it fits.
"""

from __future__ import annotations

import functools
import hashlib
import inspect
import os
import sys
from collections.abc import Callable

SHARED_CACHE_ENV = "MATERIAL_STRUCTURES_NUMBA_CACHE"

_PENDING: list[tuple[Callable, bool]] = []  # numba_callable functions not yet registered with numba
_ACTIVE = False

# the modules whose code or constants the compiled tracer is built from: its numba functions, the
# functions they call or inline, the constants they read (``test_teeth_numba_kernels`` checks that every
# module that imports numba, and every teeth module one of those imports from, is listed)
KERNEL_MODULES = ("blend_spread", "bvh", "compiled_scene", "dentin_reach_grid", "fresnel", "numba_kernels",
                  "path_tracer", "path_tracer_compiled", "phase_function", "ray_queries", "sigmoid_blend", "work_queue")
_HERE = os.path.dirname(os.path.abspath(__file__))


def numba_callable(fn: Callable | None = None, *, inline: bool = False) -> Callable:
    """Make the numpy function ``fn`` callable from numba-compiled code too (module docstring); returns ``fn``
    unchanged. Compiled with numba's numpy error model (a division by zero gives inf or NaN, as in numpy).
    ``inline=True`` has LLVM inline it into its callers (``forceinline``; for the few-operation helpers of the
    traversal loops: inlining in numba's IR would copy it into every call site and double the tracer's compile).
    Where numba is not installed this does nothing."""
    if fn is None:
        return functools.partial(numba_callable, inline=inline)
    _PENDING.append((fn, inline))
    if _ACTIVE or "numba" in sys.modules:
        activate()
    return fn


def activate() -> bool:
    """Register the pending :func:`numba_callable` functions with numba and install the kernel cache locator.
    Numba is imported here, not when this module is (the add-on imports the physics modules, and enabling the
    extension must not import numba): each module that compiles with numba calls this right after importing
    it. Returns whether numba is available."""
    global _ACTIVE
    try:
        from numba.extending import overload
    except ImportError:  # numba is optional (the numpy tracer runs without it)
        return False
    if not _ACTIVE:
        _install_locator()
        _ACTIVE = True
    while _PENDING:
        fn, inline = _PENDING.pop(0)

        def typer(*args, _fn=fn, **kwargs):
            return _fn

        typer.__signature__ = inspect.signature(fn)  # numba checks that the implementation's signature matches
        overload(fn, jit_options={"error_model": "numpy", "forceinline": inline})(typer)
    return True


def kernel_files(folder: str = _HERE) -> list[str]:
    """The source files of ``KERNEL_MODULES`` in ``folder``."""
    return [os.path.join(folder, name + ".py") for name in KERNEL_MODULES]


@functools.cache
def _digest(stats: tuple) -> str:
    h = hashlib.sha256()
    for path, _, _ in stats:
        h.update(os.path.basename(path).encode() + b"\0")
        try:
            with open(path, "rb") as f:
                h.update(f.read())
        except OSError:
            h.update(b"<missing>")
        h.update(b"\0")
    return h.hexdigest()


def kernel_sources_digest(folder: str = _HERE) -> str:
    """SHA-256 of the sources of ``KERNEL_MODULES`` in ``folder`` (names and contents, in that order).
    Re-read whenever a file's modification time or size changes."""
    stats = []
    for path in kernel_files(folder):
        try:
            st = os.stat(path)
            stats.append((path, st.st_mtime_ns, st.st_size))
        except OSError:
            stats.append((path, 0, -1))
    return _digest(tuple(stats))


def _shared_cache_path(folder: str) -> str | None:
    """``<SHARED_CACHE_ENV>/teeth-<digest>`` where the variable is set and that folder can be written, else None."""
    base = os.environ.get(SHARED_CACHE_ENV)
    if not base:
        return None
    path = os.path.join(os.path.abspath(base), "teeth-" + kernel_sources_digest(folder)[:20])
    try:
        os.makedirs(path, exist_ok=True)
    except OSError:
        return None
    return path if os.access(path, os.W_OK) else None


def _install_locator() -> None:
    """Put :class:`KernelSourcesLocator` first in numba's list of cache locators (once per process)."""
    from numba.core import caching

    # numba's list of cache locators (``CacheImpl``, ``_CacheImpl`` before numba 0.61)
    impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)
    if impl is None:
        return

    class KernelSourcesLocator(caching._CacheLocator):
        """numba cache locator for the functions of ``KERNEL_MODULES``: numba's own place and name for them, or the
        shared folder of ``SHARED_CACHE_ENV`` where that is writable; the source stamp is
        ``kernel_sources_digest()``, so an edit of any kernel module makes the index of every such function stale,
        and a copy of the same sources elsewhere finds it."""

        def __init__(self, inner, folder: str, shared: str | None):
            self._inner = inner
            self._folder = folder
            self._shared = shared
            # numba names the source file in its "cannot cache" warning (CacheImpl.check_cachable)
            self._py_file = getattr(inner, "_py_file", os.path.join(folder, "numba_kernels.py"))

        def ensure_cache_path(self):
            if self._shared is None:
                self._inner.ensure_cache_path()
            else:
                super().ensure_cache_path()

        def get_cache_path(self):
            return self._shared or self._inner.get_cache_path()

        def get_disambiguator(self):
            return self._inner.get_disambiguator()

        def get_source_stamp(self):
            return kernel_sources_digest(self._folder)

        @classmethod
        def from_function(cls, py_func, py_file):
            path = os.path.abspath(py_file)
            folder, name = os.path.split(path)
            if os.path.splitext(name)[0] not in KERNEL_MODULES or not os.path.exists(
                    os.path.join(folder, "numba_kernels.py")):
                return None
            for other in impl._locator_classes:
                if other is cls or getattr(other, "__name__", "") == cls.__name__:
                    continue
                inner = other.from_function(py_func, py_file)
                if inner is not None:
                    return cls(inner, folder, _shared_cache_path(folder))
            return None

    # first in line, and once per process (a copy of this package imported beside it finds its own class there)
    if not any(getattr(c, "__name__", "") == "KernelSourcesLocator" for c in impl._locator_classes):
        impl._locator_classes.insert(0, KernelSourcesLocator)
