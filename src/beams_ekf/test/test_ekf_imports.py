"""ekf_node's start: its imports leave out scipy.stats (a second of a two-second start on the 2-core
machine), and filterpy still gives whatever is asked of the modules it stands in for."""

import subprocess
import sys

PROBE = """
import sys
import numpy as np
import beams_ekf.ekf_node
heavy = sorted(m for m in ("scipy.stats", "scipy.ndimage") if m in sys.modules)
from filterpy.kalman import ExtendedKalmanFilter
ekf = ExtendedKalmanFilter(2, 1)
ekf.update(np.array([[1.0]]), lambda x: np.array([[1.0, 0.0]]), lambda x: x[:1])
from filterpy.stats import logpdf
from filterpy.discrete_bayes import normalize
likelihoods = round(float(ekf.log_likelihood), 9), round(float(logpdf(1.0, 0.0, 2.0)), 9)
print(heavy, *likelihoods, normalize(np.ones(2)))
"""


def test_ekf_node_imports_no_scipy_stats_and_filterpy_stays_whole():
    result = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    # the log-likelihood of z = 1 with x = 0, P = I, R = 1: S = 2 (filterpy's own numbers, through scipy)
    assert result.stdout.split() == ["[]", "-1.515512123", "-1.515512123", "[0.5", "0.5]"], result.stdout
