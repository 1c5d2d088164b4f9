"""Every path and module a document names exists: a moved file or module fails here, not in a reader's hands.

Paths are the repository's own (`src/...`, `test/...`, `bench/...`, `docs/...`, `scripts/...`, `firmware/...`,
`compat/...`); modules are dotted names of the project's packages (`beams_ekf.localiser`, an attribute after
the module too: `beams_ekf.localiser.Localiser` needs `Localiser` defined in that module).
"""

import pathlib
import re

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
# migration.md names the old names on purpose
DOCUMENTS = sorted(
    [ROOT / "README.md", ROOT / "DEVELOPING.md", ROOT / "BENCHMARKS.md", *ROOT.glob("docs/*.md")],
)
DOCUMENTS.remove(ROOT / "docs" / "migration.md")
# what a build makes (firmware images) is named before it exists
BUILT = ("firmware/build/",)
PATH = re.compile(r"(?<![\w/.-])((?:src|test|bench|docs|scripts|firmware|compat)/[\w./*-]*[\w*])")
MODULE = re.compile(
    r"(?<![\w/.-])(beams_(?:common|driver|sim|triangulation|ekf|calibration|tools|thesis|bringup)(?:\.\w+)+)"
)


def _path_exists(name: str) -> bool:
    if name.startswith(BUILT):
        return True
    if "*" in name:
        return any(ROOT.glob(name))
    return (ROOT / name).exists()


def _module_file(parts: list[str]) -> tuple[pathlib.Path | None, list[str]]:
    """The longest module prefix of a dotted name, as a file, and the attributes after it."""
    package = ROOT / "src" / parts[0] / parts[0]
    for count in range(len(parts), 0, -1):
        base = package.joinpath(*parts[1:count])
        for candidate in (base.with_suffix(".py"), base / "__init__.py"):
            if count > 1 and candidate.is_file():
                return candidate, parts[count:]
        if count == 1 and (package / "__init__.py").is_file():
            return package / "__init__.py", parts[1:]
    return None, parts


# entry-point groups are dotted names too (`beams_driver.edge_sources`): declared in a setup.py
ENTRY_POINT_GROUPS = set(
    re.findall(r'"(beams_\w+\.\w+)":', " ".join(p.read_text() for p in ROOT.glob("src/*/setup.py")))
)


def _module_exists(name: str) -> bool:
    if name in ENTRY_POINT_GROUPS:
        return True
    module, attributes = _module_file(name.split("."))
    if module is None:
        return False
    if not attributes:
        return True
    # an attribute of the module: defined or imported in it (a class's member: defined anywhere in it)
    return re.search(rf"\b{re.escape(attributes[0])}\b", module.read_text()) is not None


def _names(document: pathlib.Path) -> tuple[set[str], set[str]]:
    text = document.read_text()
    return set(PATH.findall(text)), set(MODULE.findall(text))


@pytest.mark.parametrize("document", DOCUMENTS, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_named_path_and_module_exists(document):
    paths, modules = _names(document)
    missing = sorted(p for p in paths if not _path_exists(p)) + sorted(
        m for m in modules if not _module_exists(m)
    )
    assert not missing, f"{document.relative_to(ROOT)} names what does not exist: {missing}"
