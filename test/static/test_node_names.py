"""Each node's executable is named as the node it runs (read from the source, no ROS needed): run_node
takes the node's role under its executable's name (beams_common.ros.standby), before the node exists."""

import pathlib
import re

SRC = pathlib.Path(__file__).resolve().parents[2] / "src"
# "ekf_node = beams_ekf.ekf_node:main" in a setup.py's console_scripts
NODE_SCRIPT = re.compile(r'"(\w+_node) = (\w+)\.(\w+):main"')


def test_every_node_executable_runs_a_node_of_its_name():
    scripts = [
        match.groups()
        for setup in SRC.glob("*/setup.py")
        for match in NODE_SCRIPT.finditer(setup.read_text())
    ]
    assert len(scripts) >= 6, scripts  # sim_world, driver, triangulation, ekf, calibration, fault relay
    for executable, package, module in scripts:
        source = (SRC / package / package / f"{module}.py").read_text()
        assert "run_node(" in source, executable
        assert re.findall(r'super\(\).__init__\("(\w+)"', source) == [executable], executable
