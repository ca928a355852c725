"""Command-line applications (each exposes ``main(argv) -> int``; ``jaxnav.cli`` dispatches)."""
