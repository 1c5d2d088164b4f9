"""Every test is marked with its tier by where it lives, so a new test is marked by its folder:

    src/<package>/test/      unit      (pure modules, one package; no DDS)
    test/unit/               unit      (pure modules across packages)
    test/scenario/           scenario  (offline simulated matches, replays, command-line tools on bags)
    test/dds/                dds       (installed nodes as processes, over DDS)
    test/thesis/             thesis    (the thesis's figures and tables reproduced)
    test/static/             static    (the source and the docs: layering, generated docs in sync)

`make test-fast` is `-m "not dds"`; test/static/test_test_tiers.py fails on a test file outside a tier.
"""

import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parent
TIERS = ("unit", "scenario", "dds", "thesis", "static")


def tier_of(path: pathlib.Path) -> str | None:
    """The tier of a test file by its folder, None outside every tier folder."""
    try:
        parts = path.resolve().relative_to(ROOT).parts
    except ValueError:
        return None
    if len(parts) >= 4 and parts[0] == "src" and parts[2] == "test":
        return "unit"
    if len(parts) >= 3 and parts[0] == "test" and parts[1] in TIERS:
        return parts[1]
    return None


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        tier = tier_of(item.path)
        if tier is not None:
            item.add_marker(tier)
