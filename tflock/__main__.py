"""Entry point of ``tflock`` and ``python -m tflock``.

A SIGINT / SIGTERM that arrives while the CLI loads (typer, rich, pydantic) is held until the imports finish and
then ends the process with exit code 130 and one line, so no module is left half-imported. Once a command runs,
SIGTERM behaves like Ctrl-C (KeyboardInterrupt) unless the command installs its own handling (``tflock sim`` stops
between steps); an interrupt that no command handles also ends with exit code 130 and no traceback.
"""

import signal
import sys


def entry() -> None:
    """Run the CLI."""
    held: list[int] = []
    signal.signal(signal.SIGTERM, lambda signum, frame: held.append(signum))
    signal.signal(signal.SIGINT, lambda signum, frame: held.append(signum))
    from tflock.cli import main

    try:  # (an interrupt while the handlers change is caught too)
        signal.signal(signal.SIGTERM, signal.default_int_handler)
        signal.signal(signal.SIGINT, signal.default_int_handler)
        if held:  # held while the CLI loaded, or before its handlers were in place
            print("interrupted during start-up", file=sys.stderr)
            raise SystemExit(130)
        main()
    except KeyboardInterrupt:
        code: object = 130
    except SystemExit as e:
        code = e.code
    else:
        code = 0
    clear_interrupt_mark()
    raise SystemExit(code)


def clear_interrupt_mark() -> None:
    """Let the exit code we chose stand after a KeyboardInterrupt that was caught.

    CPython 3.10-3.12 marks a KeyboardInterrupt raised inside ``exec`` of source text (dataclasses, typing helpers
    and pydantic build functions that way) as unhandled even when an outer ``except`` catches it, and then ends the
    process with SIGINT (exit -2) instead of the code passed to ``sys.exit``. The mark is a plain C int in 3.10 and
    3.11; in 3.12 it moved into the runtime state, where this does nothing.
    """
    import ctypes  # here, not at the top: the entry point's signal handling starts before anything else loads

    try:
        ctypes.c_int.in_dll(ctypes.pythonapi, "_Py_UnhandledKeyboardInterrupt").value = 0
    except ValueError:  # symbol not exported (3.12)
        pass


if __name__ == "__main__":
    entry()
