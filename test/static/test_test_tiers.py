"""The tests live in tier folders, and each tier is a marker pytest.ini declares (conftest.py)."""

import configparser
import importlib.util
import pathlib

ROOT = pathlib.Path(__file__).resolve().parents[2]


def _tiers_module():
    spec = importlib.util.spec_from_file_location("beams_test_tiers", ROOT / "conftest.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_test_file_lives_in_a_tier_folder():
    tiers = _tiers_module()
    outside = [
        str(path.relative_to(ROOT))
        for path in sorted([*ROOT.glob("test/**/test_*.py"), *ROOT.glob("src/*/test/**/test_*.py")])
        if tiers.tier_of(path) is None
    ]
    assert not outside, f"move these into test/<tier>/ ({', '.join(tiers.TIERS)}): {outside}"


def test_the_folder_gives_the_tier():
    tiers = _tiers_module()
    assert tiers.tier_of(ROOT / "src/beams_ekf/test/test_ekf_localiser.py") == "unit"
    assert tiers.tier_of(ROOT / "test/dds/test_ekf_node.py") == "dds"
    assert tiers.tier_of(ROOT / "test/thesis/test_calibration_thesis_results.py") == "thesis"
    assert tiers.tier_of(ROOT / "test/test_somewhere.py") is None
    assert tiers.tier_of(pathlib.Path("/elsewhere/test/dds/test_x.py")) is None


def test_pytest_ini_declares_every_tier_marker():
    config = configparser.ConfigParser()
    config.read(ROOT / "pytest.ini")
    declared = {
        line.split(":")[0].strip() for line in config["pytest"]["markers"].splitlines() if line.strip()
    }
    assert set(_tiers_module().TIERS) <= declared


def test_the_declared_file_times_name_test_files_and_mark_the_slow_ones():
    """conftest.py's FILE_SECONDS orders the runs: a renamed or deleted file would silently lose its
    place (it would run last), so every name there is a test file of a tier."""
    tiers = _tiers_module()
    names = {path.name for path in [*ROOT.glob("test/**/test_*.py"), *ROOT.glob("src/*/test/**/test_*.py")]}
    assert not set(tiers.FILE_SECONDS) - names, sorted(set(tiers.FILE_SECONDS) - names)
    slow = {name for name, seconds in tiers.FILE_SECONDS.items() if seconds >= tiers.SLOW_S}
    assert "test_fault_campaign.py" in slow and "test_ekf_node.py" not in slow
