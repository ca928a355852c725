"""Command-line applications (each exposes ``main(argv) -> int``; ``jaxnav.cli`` dispatches)."""

from __future__ import annotations

import sys

from jaxnav.io.errors import InputError

#: The errors a command reports as one line with exit code 2 (bad input, not a bug).
INPUT_ERRORS = (InputError, ValueError, FileNotFoundError, FileExistsError)


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
