"""The one way jaxnav's readers get a file's text: plain, gzip / Z / bz2 / zip, and (RINEX
observation files) Hatanaka-compressed, expanded in memory by the ``hatanaka`` package."""

from __future__ import annotations

from pathlib import Path

from jaxnav.io.errors import InputError


def read_text(path: Path, what: str = "RINEX") -> str:
    """File -> ASCII text (undecodable bytes replaced): decompressed when its magic bytes say so
    (gzip 1f 8b, Unix compress 1f 9d, bzip2 BZh, zip PK) and Hatanaka-expanded when it starts
    with a CRINEX header. Unreadable or corrupt files raise ``InputError`` naming the file."""
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read {what} file: {exc}", file=path) from exc
    compressed = raw[:2] in (b"\x1f\x8b", b"\x1f\x9d") or raw[:3] == b"BZh" or raw[:2] == b"PK"
    formats = "plain, gzip/Z/bz2/zip" + (" and/or Hatanaka-compressed" if what == "RINEX" else "")
    if compressed or b"CRINEX VERS" in raw[:80]:
        # hatanaka.decompress undoes .gz/.Z/.bz2/.zip and the Hatanaka (CRX) compression
        import hatanaka

        try:
            raw = hatanaka.decompress(raw)
        except Exception as exc:  # noqa: BLE001 - any decoder failure is bad input
            raise InputError(
                f"cannot decompress ({type(exc).__name__}: {exc})",
                file=path,
                expected=f"{formats} {what}",
            ) from exc
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", errors="replace")
    return raw
