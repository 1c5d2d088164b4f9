"""DEVELOPING.md's line count is the code's: a change that adds lines says so where a reader looks."""

import importlib.util
import pathlib

ROOT = pathlib.Path(__file__).resolve().parents[2]


def _line_count():
    spec = importlib.util.spec_from_file_location("line_count", ROOT / "scripts" / "line_count.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_developing_md_prints_the_line_count():
    line_count = _line_count()
    text = (ROOT / "DEVELOPING.md").read_text()
    printed = text.split(line_count.BEGIN, 1)[1].split(line_count.END, 1)[0].strip()
    assert printed == line_count.table(), "run `python scripts/line_count.py --write DEVELOPING.md`"


def test_the_count_matches_wc():
    """The same files as the documented `find ... | xargs wc -l` (test and build folders excluded)."""
    counted = sum(_line_count().counts().values())
    files = [
        p
        for top in ("src", "bench", "firmware")
        for p in (ROOT / top).rglob("*")
        if p.suffix in (".py", ".c", ".h") and "/test/" not in str(p) and "/build/" not in str(p)
    ]
    assert counted == sum(len(p.read_bytes().splitlines()) for p in files)
