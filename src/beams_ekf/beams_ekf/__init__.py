"""The BeAMS EKF (thesis ch. 6 with the odometry): filterpy's ExtendedKalmanFilter fed every bearing.

filterpy's package imports every filter it has, and with filterpy.stats scipy.stats: a second of
ekf_node's two-second start on the 2-core machine, for modules this EKF never uses. Its EKF module takes
only `logpdf` from filterpy.stats, for a likelihood this EKF never asks for: filterpy.stats and
filterpy.discrete_bayes are stand-ins that load the real module at their first use.
"""

import importlib
import sys
import types


class _LoadedAtFirstUse(types.ModuleType):
    def real(self) -> types.ModuleType:
        if sys.modules.get(self.__name__) is self:
            del sys.modules[self.__name__]
        return importlib.import_module(self.__name__)

    def __getattr__(self, name: str):
        if name.startswith("__"):  # the import machinery's probes
            raise AttributeError(name)
        return getattr(self.real(), name)


if "filterpy" not in sys.modules:  # its submodules neither: the stand-ins go in before the package
    _stats = sys.modules["filterpy.stats"] = _LoadedAtFirstUse("filterpy.stats")
    _stats.logpdf = lambda *args, **kwargs: _stats.real().logpdf(*args, **kwargs)
    sys.modules["filterpy.discrete_bayes"] = _LoadedAtFirstUse("filterpy.discrete_bayes")
