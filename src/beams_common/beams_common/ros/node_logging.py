"""Logging from a node at a severity chosen at run time, without tripping rclpy's call-site cache.

rclpy remembers the severity, name and filters of each logging call site (file, function, line,
instruction) and raises "Logger severity cannot be changed between calls" when one site logs at another
severity (rclpy/impl/rcutils_logger.py). A helper that picks the severity at run time must therefore
reach rclpy from one site per severity (`log_at`), and throttle by itself (`ThrottledLog`), never with
rclpy's per-site throttle_duration_sec: that one would also make one message's flood hide another's.
"""

from typing import Any

from beams_common.status.log_throttle import KeyThrottle

SEVERITIES = ("info", "warn", "error")


def log_at(logger: Any, severity: str, text: str) -> None:
    """Log `text` at `severity` ('info', 'warn' or 'error'): one rclpy call site per severity."""
    if severity == "error":
        logger.error(text)
    elif severity == "warn":
        logger.warning(text)
    elif severity == "info":
        logger.info(text)
    else:
        raise ValueError(f"a log severity is one of {SEVERITIES}, got {severity!r}")


class ThrottledLog:
    """A node's log lines at any severity, each key at most once every `period_s` seconds; a line
    admitted after a quiet spell says how many of its key were held back meanwhile."""

    def __init__(self, logger: Any, period_s: float = 1.0, throttle: KeyThrottle | None = None) -> None:
        self._logger = logger
        self._throttle = throttle or KeyThrottle(period_s)

    def log(self, severity: str, key: str, text: str) -> bool:
        """Log `text` unless `key` is throttled; True when it was logged."""
        if severity not in SEVERITIES:
            raise ValueError(f"a log severity is one of {SEVERITIES}, got {severity!r}")
        held_back = self._throttle.admit(key)
        if held_back is None:
            return False
        suffix = f" ({held_back} more like it not logged)" if held_back else ""
        log_at(self._logger, severity, text + suffix)
        return True
