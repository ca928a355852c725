"""``jaxnav tutorial``: copy the tutorial notebooks out of the installed package.

The notebooks live in ``jaxnav/apps/notebooks/`` as jupytext "percent" scripts (plain Python that
runs as a script and opens as a notebook). This command writes each one into a folder the user
names, as the script and, when jupytext is installed (``pip install "jaxnav[notebook]"``), as a
``.ipynb`` converted from it. Nothing is replaced without ``--overwrite``; the notebooks write
their own results below the folder they run in, never into the project's committed renderings.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

NOTEBOOKS = Path(__file__).with_name("notebooks")


def notebooks() -> dict[str, Path]:
    """Name (file stem) -> path of every tutorial notebook shipped in the package."""
    return {p.stem: p for p in sorted(NOTEBOOKS.glob("*.py"))}


def _jupytext():
    try:
        import jupytext
    except ImportError:
        return None
    return jupytext


def write_tutorial(out: Path, *, overwrite: bool = False) -> list[Path]:
    """Write every notebook into ``out`` as ``NAME.py`` and, with jupytext, ``NAME.ipynb``.

    Raises ``FileExistsError`` naming the first file that exists when ``overwrite`` is false
    (before anything is written), ``NotADirectoryError`` when ``out`` is a file.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"{out} is a file, not a folder")
    jupytext = _jupytext()
    targets = []
    for name, src in notebooks().items():
        targets.append((src, out / f"{name}.py", False))
        if jupytext is not None:
            targets.append((src, out / f"{name}.ipynb", True))
    if not overwrite:
        for _, dst, _ in targets:
            if dst.exists():
                raise FileExistsError(f"{dst} exists; pass --overwrite to replace it")
    out.mkdir(parents=True, exist_ok=True)
    for src, dst, as_notebook in targets:
        text = src.read_text()
        if as_notebook:
            # Unexecuted: the user runs it (the percent script's cells become notebook cells).
            jupytext.write(jupytext.reads(text, fmt="py:percent"), dst, fmt="ipynb")
        else:
            dst.write_text(text)
    return [dst for _, dst, _ in targets]


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="jaxnav tutorial",
        description="Copy the tutorial notebook (define an outage study, run it, read the "
                    "Dataset, the tables and the plots) into a folder: as a Python script and, "
                    "with jupytext installed (pip install \"jaxnav[notebook]\"), as .ipynb.")
    ap.add_argument("--out", type=Path, default=Path("jaxnav-tutorial"),
                    help="folder to write the notebook into (default jaxnav-tutorial; created)")
    ap.add_argument("--overwrite", action="store_true",
                    help="replace notebook files that already exist in --out")
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        written = write_tutorial(args.out, overwrite=args.overwrite)
    except (FileExistsError, NotADirectoryError) as e:
        print(f"jaxnav tutorial: {e}", file=sys.stderr)
        return 2
    except OSError as e:  # a folder we may not write to, a folder in a notebook's place, ...
        print(f"jaxnav tutorial: cannot write into {args.out}: {e.strerror or e}"
              + (f" ({e.filename})" if e.filename else ""), file=sys.stderr)
        return 2
    for path in written:
        print(f"wrote {path}")
    script = next(p for p in written if p.suffix == ".py")
    notebook = next((p for p in written if p.suffix == ".ipynb"), None)
    if notebook is None:
        print("(no .ipynb: jupytext is not installed; pip install \"jaxnav[notebook]\", or open "
              "the .py in Jupyter with jupytext, or run it as a script)")
    print(f"run it: python {script} [--quick] (writes tutorial_results/ in the current folder)"
          + (f", or open {notebook.name} in Jupyter" if notebook else ""))
    return 0
