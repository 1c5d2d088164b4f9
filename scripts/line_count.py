"""The lines outside tests, per package: the table DEVELOPING.md prints (`--write DEVELOPING.md` updates it).

Counted as `find src bench firmware -name '*.py' -o -name '*.c' -o -name '*.h' | grep -v -e /test/ -e /build/
| xargs wc -l`; test/static/test_line_count.py keeps DEVELOPING.md's table equal to this count.
"""

import argparse
import pathlib
import sys
from collections import Counter

ROOT = pathlib.Path(__file__).resolve().parents[1]
BEGIN = "<!-- line count begins -->"
END = "<!-- line count ends -->"


def counts() -> Counter:
    """Lines per package (src/<package>), bench and firmware/<image>."""
    lines: Counter = Counter()
    for top in ("src", "bench", "firmware"):
        for path in sorted((ROOT / top).rglob("*")):
            relative = path.relative_to(ROOT)
            if (
                path.suffix not in (".py", ".c", ".h")
                or "test" in relative.parts
                or "build" in relative.parts
            ):
                continue
            group = "/".join(relative.parts[:2]) if top != "bench" else "bench"
            lines[group] += len(path.read_bytes().splitlines())
    return lines


def table() -> str:
    lines = counts()
    rows = [f"| `{group}` | {count} |" for group, count in sorted(lines.items())]
    return "\n".join(["| where | lines |", "|---|---|", *rows, f"| **total** | **{sum(lines.values())}** |"])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--write", type=pathlib.Path, help="replace the table between the file's markers")
    options = parser.parse_args()
    text = table()
    if options.write:
        content = options.write.read_text()
        head, rest = content.split(BEGIN, 1)
        _, tail = rest.split(END, 1)
        options.write.write_text(f"{head}{BEGIN}\n{text}\n{END}{tail}")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
