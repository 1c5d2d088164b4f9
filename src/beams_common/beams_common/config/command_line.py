"""How a command-line tool ends: exit status 0 only with a usable result, else one line and status 2."""

import functools
import os
import shutil
import sys
from collections.abc import Callable, Sequence

EXIT_REFUSED = 2
Main = Callable[[Sequence[str] | None], int]


def command(name: str, *, clean: bool = True) -> Callable[[Main], Main]:
    """Wrap a console script's `main(argv) -> int`: an exception out of it is the line `name: reason` on
    stderr and EXIT_REFUSED, never a traceback; with `clean`, what the run created at the paths its command
    line names is removed (a partial output is never taken for a result; without, a run's logs stay)."""

    def wrap(main: Main) -> Main:
        @functools.wraps(main)
        def run(argv: Sequence[str] | None = None) -> int:
            tokens = [t.split("=", 1)[-1] for t in (sys.argv[1:] if argv is None else argv)]
            absent = [t for t in tokens if clean and t and not os.path.lexists(t)]
            try:
                return main(argv)
            except Exception as error:  # whatever the input did: one line
                print(f"{name}: {reason(error)}", file=sys.stderr)
            for path in absent:
                if os.path.isdir(path) and not os.path.islink(path):
                    shutil.rmtree(path, ignore_errors=True)
                elif os.path.lexists(path):
                    os.unlink(path)
            return EXIT_REFUSED

        return run

    return wrap


def reason(error: BaseException) -> str:
    """An exception as one line: an OS error's file and cause, a refusal's text, anything else's type too."""
    if isinstance(error, OSError) and error.strerror:
        return f"{error.filename}: {error.strerror}" if error.filename else error.strerror
    text = (str(error).strip().splitlines() or [type(error).__name__])[0]
    return text if isinstance(error, ValueError | OSError) else f"{type(error).__name__}: {text}"
