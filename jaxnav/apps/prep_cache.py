"""A cache of prepared observations, so that a second ``jaxnav ppp`` on the same files is fast.

Reading and preparing a day of 30-s RINEX with its products is most of a ``jaxnav ppp`` run
(~40 of ~50 s on ESBC); the filter takes seconds. The prepared observations depend only on the
input files' bytes, the options that reach the reading and preparation, and the code that reads
and prepares them, so the key is the sha256 of

    every input file's content (name and bytes), the options (a sorted JSON), the jaxnav
    version and the source of ``jaxnav/io/`` (a changed reader is a different preparation).

The entry is a pickle of the (observations, prepared) pair, written atomically (a temporary
file renamed), in ``$JAXNAV_CACHE_DIR`` or else ``~/.cache/jaxnav``, under ``prepared/``. A
damaged or unreadable entry is ignored and rebuilt (never an error: the cache only saves
time). ``--no-cache`` bypasses it.
"""

from __future__ import annotations

import hashlib
import json
import os
import pickle
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path

import jaxnav

_IO_DIR = Path(__file__).resolve().parents[1] / "io"


def cache_dir() -> Path:
    """``$JAXNAV_CACHE_DIR/prepared`` or ``~/.cache/jaxnav/prepared``."""
    root = os.environ.get("JAXNAV_CACHE_DIR") or Path.home() / ".cache" / "jaxnav"
    return Path(root) / "prepared"


def key(files: Sequence[str | os.PathLike], options: dict) -> str:
    """sha256 over the files' names and bytes, the options and the reading code (docstring)."""
    h = hashlib.sha256()
    for f in files:
        h.update(Path(f).name.encode() + b"\0")
        with open(f, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    h.update(json.dumps(options, sort_keys=True, default=str).encode())
    h.update(jaxnav.__version__.encode())
    for src in sorted(_IO_DIR.glob("*.py")):
        h.update(src.read_bytes())
    return h.hexdigest()


def cached(files: Sequence[str | os.PathLike], options: dict, build: Callable[[], object],
           enabled: bool = True) -> tuple[object, bool, str]:
    """(value, hit, key): the cached value of (files, options), else ``build()`` stored."""
    k = key(files, options)
    path = cache_dir() / f"{k}.pkl"
    if enabled and path.is_file():
        try:
            with path.open("rb") as fh:
                return pickle.load(fh), True, k
        except (OSError, EOFError, pickle.UnpicklingError, AttributeError, ImportError):
            pass  # damaged or from other code: rebuilt below
    value = build()
    if enabled:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
            with os.fdopen(fd, "wb") as fh:
                pickle.dump(value, fh, protocol=pickle.HIGHEST_PROTOCOL)
            os.replace(tmp, path)
        except OSError:
            pass  # a read-only home: run without the cache
    return value, False, k
