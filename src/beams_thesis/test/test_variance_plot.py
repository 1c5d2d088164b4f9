"""The variance_plot command (figures 4.9-4.13): the section-4.3 simulation drawn on the theory."""

import numpy as np
import pytest

from beams_driver.codes import codes_from_strings
from beams_driver.variance import enumerated_variance_s2
from beams_thesis import variance_plot

TICK_S = 100e-9


def test_variance_plot_command_writes_a_png_and_refuses_bad_codes(tmp_path, capsys):
    output = tmp_path / "variance.png"
    assert variance_plot.main(["--codes", "111110111110", "11111001111100", "--output", str(output)]) == 0
    assert output.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert output.stat().st_size > 10_000
    assert variance_plot.main(["--codes", "1010", "10", "--output", str(tmp_path / "bad.png")]) == 2
    assert "rotation of code 1" in capsys.readouterr().err
    assert not (tmp_path / "bad.png").exists()
    # What the panels show: the coprime simulation on the theory, for a custom code too.
    code = codes_from_strings(["11111001111100"])[0]
    windows_s = np.round(np.linspace(0.1, 20.0, 60) * 2 * code.bit_time_s / TICK_S) * TICK_S
    simulated = variance_plot.simulated_normalized_variance(code, windows_s, 998401)
    theory = enumerated_variance_s2(code, windows_s)[0] / code.variance_bound_s2
    assert simulated == pytest.approx(theory, abs=0.02)
