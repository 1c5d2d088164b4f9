"""The table a benchmark prints when run alone: its rows (figure, value, unit, compared with), aligned.

Not a benchmark itself (run_all.py runs bench_*.py); imported by those run as scripts from bench/.
"""

from collections.abc import Sequence


def print_rows(table: Sequence[tuple[str, float, str, str]], unit_width: int = 13) -> None:
    """One header line, then one line per row: figure | value (4 significant digits) | unit | compared."""
    width = max(len(figure) for figure, *_ in table)
    print(f"{'figure':<{width}} | {'value':>10} | {'unit':<{unit_width}} | compared with")
    for figure, value, unit, compared in table:
        print(f"{figure:<{width}} | {value:>10.4g} | {unit:<{unit_width}} | {compared}")
