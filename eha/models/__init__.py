"""Numba kernels of the actuator models: ``hf`` (detailed), ``lf`` (monitoring), ``friction``.

The kernels are compiled with ``cache=True``. Numba caches next to this file or, when that is
read-only (a system-wide install), under the user's cache folder; when neither is writable (a
service account without a home, a read-only container) every kernel would fail to compile, so
:func:`_numba_cache_fallback` points numba at a private folder under the temporary directory.
"""

import os
import sys
import tempfile


def _writable(folder: str) -> bool:
    """Whether files can be created in ``folder`` (created if missing), as numba will try."""
    try:
        os.makedirs(folder, exist_ok=True)
        tempfile.TemporaryFile(dir=folder).close()
        return True
    except OSError:
        return False


def _user_cache_dir() -> str:
    """numba's user-wide cache folder (its AppDirs rule on Linux/macOS; %LOCALAPPDATA%)."""
    if sys.platform == "win32":
        base = os.environ.get("LOCALAPPDATA") or os.path.expanduser("~")
    elif sys.platform == "darwin":
        base = os.path.expanduser("~/Library/Caches")
    else:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache")
    return os.path.join(base, "numba")


def _numba_cache_fallback() -> str | None:
    """Set ``NUMBA_CACHE_DIR`` to ``$TMPDIR/eha-numba-<user>`` when neither this package's
    ``__pycache__`` nor the user cache folder is writable; returns the folder chosen, if any.
    An explicit ``NUMBA_CACHE_DIR`` is left alone."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return None
    here = os.path.join(os.path.dirname(os.path.abspath(__file__)), "__pycache__")
    if _writable(here) or _writable(_user_cache_dir()):
        return None
    user = os.getuid() if hasattr(os, "getuid") else os.environ.get("USERNAME", "user")
    folder = os.path.join(tempfile.gettempdir(), f"eha-numba-{user}")
    if not _writable(folder):
        return None  # nothing writable at all: numba will say it cannot cache
    os.environ["NUMBA_CACHE_DIR"] = folder
    if "numba" in sys.modules:  # numba read its configuration already
        sys.modules["numba"].config.CACHE_DIR = folder
    return folder


_numba_cache_fallback()

#: Recorded outputs of every model (:data:`eha.trace.OUTPUTS`) and their units: the kernels'
#: output array has these columns, in this order.
from eha.trace import OUTPUT_UNITS, OUTPUTS  # noqa: E402  (imports nothing of eha)
O_T, O_COM, O_XU, O_XJ, O_DXJ, O_XS, O_XF, O_P12, O_COR = range(len(OUTPUTS))

# eha.models.friction.record writes the columns in this order.
assert OUTPUTS.index("t") == 0 and OUTPUTS.index("cor") == 8


def use_one_numba_thread() -> None:
    """Initialiser of a worker process: one numba thread (the LF batch kernel is parallel and
    the workers already fill the cores). Defined here, in a module that imports no numba, so
    that unpickling it in a spawned worker sets the variable before numba is first imported."""
    os.environ["NUMBA_NUM_THREADS"] = "1"
