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
