"""A cache of prepared observations, so that a second ``jaxnav ppp`` on the same files is fast.

Reading and preparing a day of 30-s RINEX with its products is most of a ``jaxnav ppp`` run
(~40 of ~50 s on ESBC); the filter takes seconds. The prepared observations depend only on the
input files' bytes, the options that reach the reading and preparation, and the code that reads
and prepares them, so the key is the sha256 of

    every input file's role (its option), name and bytes, the options (a sorted JSON) and the
    source of the whole jaxnav package (``study.sweep.source_hash``: the preparation runs code
    of ``io/``, ``gnss/``, ``core/`` and ``geodesy``; any edit is a different preparation).

The entry is a pickle of the (observations, prepared) pair, written atomically (a temporary
file renamed), in ``$JAXNAV_CACHE_DIR`` or else ``~/.cache/jaxnav``, under ``prepared/``. An
entry that cannot be loaded, for whatever reason, is rebuilt (never an error: the cache only
saves time). ``--no-cache`` reads the files and rewrites the entry.
"""

from __future__ import annotations

import hashlib
import json
import os
import pickle
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path


def cache_dir() -> Path:
    """``$JAXNAV_CACHE_DIR/prepared`` or ``~/.cache/jaxnav/prepared``."""
    root = os.environ.get("JAXNAV_CACHE_DIR") or Path.home() / ".cache" / "jaxnav"
    return Path(root) / "prepared"


def key(files: Sequence[tuple[str, str | os.PathLike]], options: dict) -> str:
    """sha256 over the (role, file) names and bytes, the options and the package source."""
    from jaxnav.study.sweep import source_hash

    h = hashlib.sha256()
    for role, f in files:
        h.update(f"{role}\0{Path(f).name}\0".encode())
        with open(f, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    h.update(json.dumps(options, sort_keys=True, default=str).encode())
    h.update(source_hash().encode())
    return h.hexdigest()


def cached(files: Sequence[tuple[str, str | os.PathLike]], options: dict,
           build: Callable[[], object], read: bool = True) -> tuple[object, bool, str]:
    """(value, hit, key): the cached value of (files, options) when ``read`` and loadable, else
    ``build()``, stored for the next run."""
    k = key(files, options)
    path = cache_dir() / f"{k}.pkl"
    if read and path.is_file():
        try:
            with path.open("rb") as fh:
                return pickle.load(fh), True, k
        except Exception:  # noqa: BLE001 (any damaged / foreign entry is rebuilt below)
            pass
    value = build()
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
        with os.fdopen(fd, "wb") as fh:
            pickle.dump(value, fh, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(tmp, path)
        tmp = None
    except (OSError, pickle.PicklingError):
        pass  # a read-only home or an unpicklable value: run without the cache
    finally:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
    return value, False, k
