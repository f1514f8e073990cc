"""Entry point of ``tflock`` and ``python -m tflock``.

SIGTERM is mapped to KeyboardInterrupt before anything heavy is imported, and an interrupt that arrives before a
command has installed its own handling (while Taichi, Rerun and typer load) ends the process with exit code 130
and no traceback.
"""

import signal


def entry() -> None:
    """Run the CLI."""
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        from tflock.cli import main

        main()
    except KeyboardInterrupt:
        raise SystemExit(130) from None


if __name__ == "__main__":
    entry()
