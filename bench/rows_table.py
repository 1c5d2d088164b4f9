"""What a benchmark does when run alone: its options from its `rows` keywords, its rows printed aligned.

Not a benchmark itself (run_all.py runs bench_*.py); imported by those run as scripts from bench/.
"""

import argparse
import inspect
import pathlib
import time
import timeit
from collections.abc import Callable, Sequence

Row = tuple[str, float, str, str]


def best_per_call_s(function: Callable[[], object], number: int, repeat: int = 7) -> float:
    """Fastest mean time per call (s) of `repeat` rounds of `number` calls: the machine is shared, the
    least disturbed round is the figure."""
    return min(timeit.repeat(function, number=number, repeat=repeat)) / number


def budget_row(figure: str, value: float, unit: str, limit: float, at_least: bool = False) -> Row:
    """A figure beside its budget, `met` or `MISSED` (bench_main exits 1 on a miss)."""
    met = value >= limit if at_least else value <= limit
    verdict = "met" if met else "MISSED"
    return figure, value, unit, f"budget {'>=' if at_least else '<='} {limit:.3g}: {verdict}"


def print_rows(table: Sequence[Row], unit_width: int = 13) -> None:
    """One header line, then one line per row: figure | value (4 significant digits) | unit | compared."""
    width = max(len(figure) for figure, *_ in table)
    print(f"{'figure':<{width}} | {'value':>10} | {'unit':<{unit_width}} | compared with")
    for figure, value, unit, compared in table:
        shown = f"{value:>10.4g}" if isinstance(value, float | int) else f"{value!s:>10}"
        print(f"{figure:<{width}} | {shown} | {unit:<{unit_width}} | {compared}")


def bench_main(doc: str, rows: Callable[..., Sequence[tuple]], argv: Sequence[str] | None = None) -> int:
    """Run `rows` with its keywords as options (`--flood-s` for `flood_s`: the default's type, a list's
    items repeated, a path for a None default) and print the table; 1 when a budget row is MISSED."""
    parser = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    for name, parameter in inspect.signature(rows).parameters.items():
        default = parameter.default
        if isinstance(default, bool):  # a flag: `--one-process`
            parser.add_argument(f"--{name.replace('_', '-')}", action="store_true", dest=name)
            continue
        many = isinstance(default, list | tuple)
        kind = pathlib.Path if default is None else type(default[0] if many else default)
        nargs = "+" if many else None
        parser.add_argument(f"--{name.replace('_', '-')}", type=kind, default=default, nargs=nargs, dest=name)
    table = rows(**vars(parser.parse_args(argv)))
    print_rows(table)
    return int(any(str(compared).endswith("MISSED") for *_, compared in table))


class RosProbe:
    """A bench's own rclpy node on its own context and executor, spun by hand (rclpy is imported here only:
    the benches without DDS run without it)."""

    def __init__(self, name: str) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin_until(self, predicate: Callable[[], bool], timeout_s: float, during=lambda: None) -> bool:
        """Spin (calling `during` each turn) until `predicate` holds or timeout_s passed; the predicate."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            during()
            if predicate():
                return True
            self.executor.spin_once(timeout_sec=0.01)
        return predicate()

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()
