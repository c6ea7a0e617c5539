"""gma-ffc: stress-dependent Prandtl-Ishlinskii modelling and feedforward control of GMAs."""

import os as _os

# Our matrices are small (thousands x tens): multi-threaded BLAS only makes threads fight over
# the cores, 5-8x slower identification on a 2-core lab PC, and steals time from the control
# loop. Single-threaded unless the user says otherwise; effective when gma_ffc is imported
# before numpy, as the console script does.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")

__version__ = "0.1.0"


def _writable(path: str) -> bool:
    """Could a directory be created (if missing) and written at `path`?"""
    while not _os.path.exists(path):
        parent = _os.path.dirname(path)
        if parent == path:
            return False
        path = parent
    return _os.path.isdir(path) and _os.access(path, _os.W_OK | _os.X_OK)


def _numba_cache_dir() -> None:
    """Give numba's kernel cache a place to live on a read-only install.

    Every kernel is `@njit(cache=True)`: numba keeps the compiled code beside the source
    (__pycache__) or, failing that, in ~/.cache/numba, and loads it on the next run instead of
    compiling again (seconds). Where neither is writable (a read-only image, a service account
    without a home), numba does not fall back: importing any kernel module raises "cannot cache
    function ...: no locator available". There, and only there, the cache goes to a private
    per-user directory in the temp dir (mode 0700, ours, or not used at all). A NUMBA_CACHE_DIR
    set by the user always wins.
    """
    if _os.environ.get("NUMBA_CACHE_DIR"):
        return
    if _writable(_os.path.join(_os.path.dirname(_os.path.abspath(__file__)), "__pycache__")):
        return
    user_cache = _os.environ.get("XDG_CACHE_HOME") or _os.path.expanduser("~/.cache")
    if _writable(_os.path.join(user_cache, "numba")):
        return
    import tempfile

    uid = _os.getuid() if hasattr(_os, "getuid") else None
    private = _os.path.join(tempfile.gettempdir(), "gma-ffc-numba" + ("" if uid is None else f"-{uid}"))
    try:
        _os.makedirs(private, mode=0o700, exist_ok=True)
        st = _os.stat(private)
    except OSError:
        return
    if uid is not None and (st.st_uid != uid or st.st_mode & 0o077):
        return                      # someone else's directory: never load compiled code from it
    if not _writable(private):
        return
    _os.environ["NUMBA_CACHE_DIR"] = private
    import sys

    numba = sys.modules.get("numba")
    if numba is not None:           # numba read its configuration already: tell it directly
        numba.config.CACHE_DIR = private


_numba_cache_dir()
