"""`fault_campaign`: plays a seeded schedule of faults against the whole running suite and prints what it
measured (docs/fault_campaign.md): the robot's processes (campaign_processes) with fault_relay_node between
the publishers and the filters, a probe node in this process (campaign_probe_node), the faults' timed actions
(campaign_faults), the figures and report (campaign_metrics). With --hosts the driver runs on a second host (a
network namespace), skipped and said so where namespaces cannot be made.

Usage: fault_campaign [--seed N] [--duration S] [--output DIR] [--serial] [--hosts] [-p ekf:NAME:=VALUE ...]
"""

import argparse
import concurrent.futures
import math
import multiprocessing
import os
import pathlib
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import yaml

from beams_common.config.command_line import command
from beams_tools.campaign_faults import FaultPlan
from beams_tools.campaign_hosts import Hosts, hosts_problem
from beams_tools.campaign_metrics import CampaignResult, campaign_figures
from beams_tools.campaign_probe_node import CALL_TIMEOUT_S, Probe
from beams_tools.campaign_processes import CampaignProcesses
from beams_tools.fault_schedule import (
    FAULT_CLASSES,
    LINK_CLASS,
    SERIAL_CLASS,
    Fault,
    ScheduleSettings,
    draw_schedule,
)
from beams_tools.serial_feed import SerialFeed

START_TIMEOUT_S = 90.0
RSS_PERIOD_S = 5.0
# the /diagnostics level of each LocalisationStatus code (waiting, tracking, degraded, lost), to name a
# report's level in the reasons
STATUS_LEVELS = {0: "WARN", 1: "OK", 2: "WARN", 3: "ERROR"}
# the simulator's longest match (its duration_s maximum); the robot stands still after it
SIM_MAX_MATCH_S = 600.0


@dataclass
class CampaignConfig:
    """What one campaign runs: seed, length, logs, DDS domain, parameters added to the nodes' (node -> {name:
    value}), a schedule of its own instead of the seeded draw, the serial sensor (`serial`, with the line's
    faults) and two hosts (`hosts`, with the link's faults)."""

    seed: int = 18
    duration_s: float = 150.0
    output_dir: pathlib.Path | None = None
    domain_id: int = 66  # 61-69 are the developers (test/conftest.py); the tests never use it
    overrides: dict[str, dict[str, Any]] = field(default_factory=dict)
    schedule: tuple[Fault, ...] | None = None
    warmup_s: float = 10.0
    install_base: pathlib.Path | None = None
    serial: bool = False
    # the robot on two hosts (network namespaces) joined by a link the link_down faults cut; skipped, and
    # said so, where namespaces cannot be made (hosts_problem)
    hosts: bool = False


def node_parameters(config: CampaignConfig, serial_link: pathlib.Path) -> dict[str, dict[str, Any]]:
    """Each node's parameters: a random match seeded from the campaign's seed, plus the overrides."""
    parameters: dict[str, dict[str, Any]] = {
        "sim_world": {
            "trajectory": "random",
            "trajectory_seed": config.seed,
            "odometry_seed": config.seed + 1,
            "duration_s": min(SIM_MAX_MATCH_S, config.duration_s + 60.0),
        },
        "driver": (
            {"source": "serial", "device": str(serial_link)}
            if config.serial
            else {"sim_sensor_seed": config.seed + 2}
        ),
        "triangulation": {"publish_markers": False},
        "ekf": {},
        "fault_relay": {},
        "calibration": {"dataset_file": str(pathlib.Path(config.output_dir) / "calibration_dataset.yaml")},
    }
    for name, values in config.overrides.items():
        parameters[name].update(values)
    return parameters


class Campaign:
    """One campaign: processes, probe, the faults' timed actions; `run` returns the result."""

    def __init__(self, config: CampaignConfig) -> None:
        self.config = config
        if config.install_base is None:
            config.install_base = pathlib.Path(os.environ.get("BEAMS_INSTALL_BASE", "install")).resolve()
        if config.output_dir is None:
            config.output_dir = pathlib.Path(tempfile.mkdtemp(prefix="fault_campaign_"))
        self.log_dir = pathlib.Path(config.output_dir)
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.notes: list[str] = []
        problem = hosts_problem() if config.hosts else ""
        if problem:
            self.notes.append(f"{LINK_CLASS}: skipped here, {problem}")
            print(f"fault_campaign: {self.notes[-1]}", file=sys.stderr, flush=True)
        self.hosts = Hosts(str(os.getpid())) if config.hosts and not problem else None
        self.schedule = (
            config.schedule
            if config.schedule is not None
            else seeded_schedule(config, self.hosts is not None)
        )
        self.serial_link = self.log_dir / "beams_sensor"
        self.feed: SerialFeed | None = None
        env = dict(
            os.environ,
            ROS_DOMAIN_ID=str(config.domain_id),
            # across the hosts' link; the subnet exists only inside the campaign's namespaces
            ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST" if self.hosts is None else "SUBNET",
            PYTHONUNBUFFERED="1",
        )
        self.processes = CampaignProcesses(
            config.install_base,
            self.log_dir,
            env,
            node_parameters(config, self.serial_link),
            self.hosts.exec_prefix if self.hosts is not None else lambda process: [],
            self.campaign_s,
            self.current_fault,
        )
        self.t0_s = math.nan
        self.probe: Probe | None = None

    def campaign_s(self) -> float:
        return self.probe.now_s() - self.t0_s

    def current_fault(self) -> str:
        now = self.campaign_s()
        for fault in self.schedule:
            if fault.window[0] <= now < fault.window[1]:
                return f"{fault.kind}/{fault.variant}"
        return "no fault"

    def run(self) -> CampaignResult:
        if any(fault.kind == LINK_CLASS for fault in self.schedule) and self.hosts is None:
            raise ValueError(f"{LINK_CLASS} faults need hosts=True where namespaces can be made")
        discovery_range = os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE")
        if self.hosts is not None:
            self.hosts.build()
            self.hosts.enter()  # the probe's participant and every process started from here
            os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "SUBNET"
        try:
            return self._run()
        finally:
            if self.hosts is not None:
                self.hosts.leave()
                self.hosts.remove()
                if discovery_range is None:
                    os.environ.pop("ROS_AUTOMATIC_DISCOVERY_RANGE", None)
                else:
                    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = discovery_range

    def _run(self) -> CampaignResult:
        self.probe = probe = Probe(self.config.domain_id)
        processes = self.processes
        if self.config.serial:
            self.feed = SerialFeed(self.serial_link, probe.pose_at, self.config.seed + 2)
        try:
            processes.start()
            deadline = time.monotonic() + START_TIMEOUT_S
            while not probe.ekf:
                if time.monotonic() > deadline:
                    raise RuntimeError(f"no EKF estimate within {START_TIMEOUT_S} s; logs in {self.log_dir}")
                probe.spin(0.05)
            self.t0_s = probe.now_s()
            faults = FaultPlan(probe, processes, self.feed, self.hosts)
            faults.add(self.schedule)
            next_rss_s = self.config.warmup_s
            while self.campaign_s() < self.config.duration_s:
                probe.spin(0.01)
                now = self.campaign_s()
                faults.run_due(now)
                probe.poll_calls()
                processes.poll()
                if now >= next_rss_s:
                    processes.sample_rss(now)
                    next_rss_s += RSS_PERIOD_S
            end_s = probe.now_s()
            while probe.pending and probe.now_s() < end_s + CALL_TIMEOUT_S:  # the last calls' answers
                probe.spin(0.05)
                probe.poll_calls()
            processes.poll()
        finally:
            processes.stop()
            if self.feed is not None:
                self.feed.close()
            ekf, truth, status = (
                np.array(rows, dtype=float) for rows in (probe.ekf, probe.truth, probe.status)
            )
            messages = list(probe.status_messages)
            probe.close()
        windows = [(f.kind, self.t0_s + f.window[0], self.t0_s + f.window[1]) for f in self.schedule]
        figures = campaign_figures(
            ekf.reshape(-1, 6),
            truth.reshape(-1, 3),
            status.reshape(-1, 3),
            windows,
            self.t0_s + self.config.warmup_s,
            self.t0_s + self.config.duration_s,
            [(stamp, f"{STATUS_LEVELS.get(code, code)}: {text}") for stamp, code, text in messages],
        )
        np.savez(
            self.log_dir / "series.npz",
            ekf=ekf,
            truth=truth,
            status=status,
            t0_s=self.t0_s,
            status_stamps=np.array([row[0] for row in messages], dtype=float),
            status_codes=np.array([row[1] for row in messages], dtype=int),
            status_messages=np.array([row[2] for row in messages], dtype=str),
        )
        if probe.duplicate_estimates:
            self.notes.append(
                f"duplicate_publisher/ekf: {probe.duplicate_estimates} estimates of the second ekf_node "
                "received, not judged (its child frame tells them apart)"
            )
        result = CampaignResult(
            self.schedule,
            figures,
            probe.calls,
            processes.deaths,
            processes.rss_growth_mb(),
            self.log_dir,
            tuple(self.notes),
        )
        (self.log_dir / "report.txt").write_text(result.report() + "\n")
        return result


def seeded_schedule(config: CampaignConfig, hosts: bool) -> tuple[Fault, ...]:
    """The schedule the campaign's seed draws, of the classes it can play (`campaign_classes`)."""
    settings = ScheduleSettings(duration_s=config.duration_s, warmup_s=config.warmup_s)
    return draw_schedule(config.seed, settings, campaign_classes(config.serial, hosts))


def campaign_classes(serial: bool, hosts: bool = False) -> tuple[str, ...]:
    """The fault classes a campaign draws: the serial line's too when the driver reads a serial port, the
    hosts' link's when the robot runs on two hosts."""
    return (*FAULT_CLASSES, *((SERIAL_CLASS,) if serial else ()), *((LINK_CLASS,) if hosts else ()))


def run_campaign(config: CampaignConfig) -> CampaignResult:
    """Play a campaign; on two hosts, in a process of its own: Fast DDS keeps per-process network state,
    and a participant created in this process after one in another namespace stayed deaf (measured:
    a second campaign in one pytest process never saw its EKF)."""
    if config.hosts and not hosts_problem():
        spawn = multiprocessing.get_context("spawn")
        with concurrent.futures.ProcessPoolExecutor(max_workers=1, mp_context=spawn) as pool:
            return pool.submit(_run_here, config).result()
    return _run_here(config)


def _run_here(config: CampaignConfig) -> CampaignResult:
    return Campaign(config).run()


def _override(text: str) -> tuple[str, str, Any]:
    node, _, assignment = text.partition(":")
    name, _, value = assignment.partition(":=")
    if not (node and name and value):
        raise argparse.ArgumentTypeError(f"expected NODE:NAME:=VALUE, got {text!r}")
    return node, name, yaml.safe_load(value)


@command("fault_campaign", clean=False)
def main(args: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seed", type=int, default=18)
    parser.add_argument("--duration", type=float, default=150.0, help="campaign length (s) after start-up")
    parser.add_argument("--output", type=pathlib.Path, help="logs and series (default: a temporary one)")
    parser.add_argument("--domain-id", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", "66")))
    parser.add_argument(
        "-p",
        dest="overrides",
        action="append",
        type=_override,
        default=[],
        help="NODE:NAME:=VALUE (ekf:lost_nis_window_bearings:=0)",
    )
    parser.add_argument("--schedule-only", action="store_true", help="print the schedule and stop")
    parser.add_argument("--serial", action="store_true", help="the driver on a simulated serial sensor")
    parser.add_argument("--hosts", action="store_true", help="the driver on a second host (root, iproute2)")
    options = parser.parse_args(args)
    overrides: dict[str, dict[str, Any]] = {}
    for node, name, value in options.overrides:
        overrides.setdefault(node, {})[name] = value
    config = CampaignConfig(
        seed=options.seed,
        duration_s=options.duration,
        output_dir=options.output,
        domain_id=options.domain_id,
        overrides=overrides,
        serial=options.serial,
        hosts=options.hosts,
    )
    if options.schedule_only:
        schedule = seeded_schedule(config, config.hosts and not hosts_problem())
        print("\n".join(fault.describe() for fault in schedule))
        return 0
    print(run_campaign(config).report())
    return 0


if __name__ == "__main__":
    sys.exit(main())
