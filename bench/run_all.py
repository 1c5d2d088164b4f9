"""Run the benchmarks under bench/ and print one table per area: the tables BENCHMARKS.md records.

Each bench/bench_<area>.py module has `rows() -> list[(figure, value, unit, compared with)]`.
Usage (through `make bench`): python bench/run_all.py [--only AREA ...] [--record BENCHMARKS.md]
With --record, each area run replaces its own section of the file (between its "bench: <area>" markers,
added at the end when new), so the file holds the latest figure of each row with its date and command.
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


def markers(area: str) -> tuple[str, str]:
    return f"<!-- bench: {area} begins -->", f"<!-- bench: {area} ends -->"


def area_section(area: str, rows: list[tuple]) -> str:
    """One area's table, headed by when, where and with what command it was measured."""
    lines = [
        f"## {area}",
        "",
        f"Measured {datetime.date.today().isoformat()} on {platform.node()} "
        f"({platform.processor() or platform.machine()}, Python {platform.python_version()}) with "
        f"`python bench/bench_{area}.py`.",
        "",
        "| figure | value | unit | compared with |",
        "|---|---|---|---|",
    ]
    lines += [
        f"| {figure} | {format_value(value)} | {unit} | {compared} |"
        for figure, value, unit, compared in rows
    ]
    return "\n".join(lines)


def record_section(path: pathlib.Path, area: str, section: str) -> None:
    """Replace an area's section of a Markdown file (or append it), keeping everything else."""
    begin, end = markers(area)
    text = path.read_text()
    if begin in text and end in text:
        head, rest = text.split(begin, 1)
        _, tail = rest.split(end, 1)
    else:
        head, tail = text.rstrip("\n") + "\n\n", "\n"
    path.write_text(f"{head}{begin}\n{section}\n{end}{tail}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--only", nargs="*", default=None, help="areas to run (bench_<area>.py)")
    parser.add_argument("--record", type=pathlib.Path, help="also put each area's table into this file")
    options = parser.parse_args()
    paths = sorted(BENCH_DIR.glob("bench_*.py"))
    if options.only:
        paths = [p for p in paths if p.stem.removeprefix("bench_") in options.only]
    failures = 0
    for path in paths:
        area = path.stem.removeprefix("bench_")
        started = time.monotonic()
        print(f"running {path.name} ...", file=sys.stderr, flush=True)
        try:
            rows = load_bench(path).rows()
        except Exception as error:  # one broken benchmark must not hide the others' figures
            print(f"{path.name} failed: {error!r}", file=sys.stderr)
            failures += 1
            continue
        section = area_section(area, rows)
        print(section + "\n")
        if options.record:
            record_section(options.record, area, section)
        print(f"{path.name}: {len(rows)} figures in {time.monotonic() - started:.1f} s", file=sys.stderr)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
