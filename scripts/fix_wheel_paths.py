"""Point the ROS wheels' exported CMake targets at this interpreter (ROS2_FROM_PYPI.md, pitfall 2).

The wheels were built with /opt/python/cp311-cp311; their CMake exports name that
interpreter's include directory and numpy's, which do not exist here.
"""

import pathlib
import sys
import sysconfig

import numpy

BUILDER_PYTHON_INCLUDE = "/opt/python/cp311-cp311/include/python3.11"
BUILDER_NUMPY_INCLUDE = "/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include"


def main() -> int:
    share = pathlib.Path(sys.prefix) / "share"
    replacements = {
        BUILDER_NUMPY_INCLUDE: numpy.get_include(),
        BUILDER_PYTHON_INCLUDE: sysconfig.get_paths()["include"],
    }
    rewritten = 0
    for path in share.rglob("*.cmake"):
        text = path.read_text(errors="surrogateescape")
        new_text = text
        for old, new in replacements.items():
            new_text = new_text.replace(old, new)
        if new_text != text:
            path.write_text(new_text, errors="surrogateescape")
            rewritten += 1
    print(f"fix_wheel_paths: rewrote {rewritten} CMake files under {share}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
