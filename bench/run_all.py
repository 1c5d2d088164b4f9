"""Run every benchmark under bench/ and print one table: the table BENCHMARKS.md records.

Each bench/bench_<area>.py module has `rows() -> list[(figure, value, unit, compared with)]`.
Usage (through `make bench`): python bench/run_all.py [--only AREA ...] [--record BENCHMARKS.md]
With --record, the table replaces what stands between the file's two "make bench: table" markers.
"""

import argparse
import datetime
import importlib.util
import pathlib
import platform
import sys
import time

BENCH_DIR = pathlib.Path(__file__).resolve().parent


def load_bench(path: pathlib.Path):
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def format_value(value: float) -> str:
    return f"{value:.4g}" if isinstance(value, float) else str(value)


BEGIN_MARK = "<!-- make bench: table begins -->"
END_MARK = "<!-- make bench: table ends -->"


def record_table(path: pathlib.Path, table: str) -> None:
    """Replace the table between the markers of a Markdown file, keeping the text around it."""
    text = path.read_text()
    if BEGIN_MARK not in text or END_MARK not in text:
        raise SystemExit(f"{path} has no {BEGIN_MARK} / {END_MARK} markers")
    head, rest = text.split(BEGIN_MARK, 1)
    _, tail = rest.split(END_MARK, 1)
    path.write_text(f"{head}{BEGIN_MARK}\n{table}\n{END_MARK}{tail}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--only", nargs="*", default=None, help="areas to run (bench_<area>.py)")
    parser.add_argument("--record", type=pathlib.Path, help="also put the table into this file (its markers)")
    options = parser.parse_args()
    paths = sorted(BENCH_DIR.glob("bench_*.py"))
    if options.only:
        paths = [p for p in paths if p.stem.removeprefix("bench_") in options.only]
    lines = [
        f"Measured {datetime.date.today().isoformat()} on {platform.node()} "
        f"({platform.processor() or platform.machine()}, Python {platform.python_version()}).",
        "",
        "| figure | value | unit | compared with | command |",
        "|---|---|---|---|---|",
    ]
    failures = 0
    for path in paths:
        started = time.monotonic()
        print(f"running {path.name} ...", file=sys.stderr, flush=True)
        try:
            rows = load_bench(path).rows()
        except Exception as error:  # one broken benchmark must not hide the others' figures
            print(f"{path.name} failed: {error!r}", file=sys.stderr)
            failures += 1
            continue
        for figure, value, unit, compared_with in rows:
            command = f"`python bench/{path.name}`"
            lines.append(f"| {figure} | {format_value(value)} | {unit} | {compared_with} | {command} |")
        print(f"{path.name}: {len(rows)} figures in {time.monotonic() - started:.1f} s", file=sys.stderr)
    table = "\n".join(lines)
    print(table)
    if options.record:
        record_table(options.record, table)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
