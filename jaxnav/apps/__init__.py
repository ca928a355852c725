"""Command-line applications (each exposes ``main(argv) -> int``; ``jaxnav.cli`` dispatches)."""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import time

from jaxnav.io.errors import InputError

#: The errors a command reports as one line with exit code 2 (bad input, not a bug).
INPUT_ERRORS = (InputError, ValueError, FileNotFoundError, FileExistsError)


def existing_file(text: str) -> str:
    """argparse ``type`` of an input-file option: the path unchanged if it names a readable
    file, else an argparse error naming the option (exit code 2 before any work starts)."""
    if not os.path.isfile(text):
        why = "is a folder, expected a file" if os.path.isdir(text) else "no such file"
        raise argparse.ArgumentTypeError(f"{text}: {why}")
    if not os.access(text, os.R_OK):
        raise argparse.ArgumentTypeError(f"{text}: not readable (permission denied)")
    return text


#: ``--solution`` values of the recorded-data commands: the forward filter, or "combined" =
#: forward filter + RTS smoother (RTKPOST's names). No "backward": running an INS backwards needs a
#: reverse-time mechanization, which jaxnav does not have.
SOLUTIONS = ("forward", "combined")


def pos_solution_label(smooth: bool) -> str:
    """The .pos header's ``solution`` value (RTKPOST's words)."""
    return "Combined (forward + RTS smoother)" if smooth else "Forward"


class Stages:
    """Progress of a command's long steps: one line per stage with its elapsed seconds, on
    stdout (nothing when ``quiet``), so reading, preparing and compiling are never silent."""

    def __init__(self, quiet: bool = False):
        self.quiet = quiet

    @contextlib.contextmanager
    def __call__(self, what: str):
        if not self.quiet:
            print(f"  {what} ...", end="", flush=True)
        t = time.perf_counter()
        try:
            yield
        except BaseException:
            if not self.quiet:
                print(" failed", flush=True)
            raise
        if not self.quiet:
            print(f" {time.perf_counter() - t:.1f} s", flush=True)


def add_solution_options(parser) -> None:
    """``--solution forward|combined`` and its shorthand ``--smooth`` (dest ``solution``)."""
    g = parser.add_mutually_exclusive_group()
    g.add_argument("--solution", choices=SOLUTIONS, default="forward",
                   help="forward filter, or combined = forward filter + RTS smoother (every "
                        "epoch from all the data, as RTKPOST's combined); default forward")
    g.add_argument("--smooth", dest="solution", action="store_const", const="combined",
                   help="same as --solution combined")


def add_plot_option(parser) -> None:
    """``--no-plots`` (dest ``no_plots``): skip ``plots.write_run_plots`` beside the .pos."""
    parser.add_argument("--no-plots", action="store_true",
                        help="skip the PNG plots and the Markdown summary beside OUT "
                             "(apps/plots.py)")


def run_command(prog: str, parser, body, argv=None) -> int:
    """Parse ``argv`` (default ``sys.argv[1:]``) with ``parser`` and return ``body(args)``; an
    input error is printed as ``PROG: error: ...`` on stderr and gives exit code 2."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(argv)
    try:
        return body(args)
    except INPUT_ERRORS as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
