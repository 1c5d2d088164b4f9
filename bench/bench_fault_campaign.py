"""The fault campaign over its full length (beams_tools.campaign_command, docs/fault_campaign.md): 20 minutes
by default, in ROS_DOMAIN_ID 66 unless the environment sets one.
"""

import os
import pathlib
import sys

from rows_table import Row, bench_main

from beams_tools.campaign_command import CampaignConfig, CampaignResult, run_campaign

BENCH_DURATION_S = 1200.0
BENCH_SEED = 18


def result_rows(result: CampaignResult) -> list[Row]:
    """The campaign's figures as bench rows (figure, value, unit, compared with)."""
    f = result.figures
    minutes = f"{f.span_s / 60:.0f}-min campaign"
    rows = [
        (f"{minutes}: hazardously misleading time", f.misleading_s, "s", "0"),
        (f"{minutes}: misleading time outside the fault windows", f.misleading_outside_s, "s", "0"),
        (f"{minutes}: largest misleading EKF error", f.max_misleading_error_m, "m", "none (0)"),
        (f"{minutes}: availability outside the fault windows", 100 * f.availability_outside, "%", ">= 95"),
        (f"{minutes}: availability over the whole campaign", 100 * f.availability, "%", "-"),
        (f"{minutes}: nodes dead", len(result.deaths), "count", "0"),
        (f"{minutes}: service calls unanswered", len(result.unanswered), f"of {len(result.calls)}", "0"),
        (f"{minutes}: answers against expectation", len(result.unexpected_answers), "count", "0"),
    ]
    for note in result.notes:
        print(f"note: {note}", file=sys.stderr)
    for kind, figures in f.per_class.items():
        rows.append((f"{minutes}: {kind} misleading time", figures.misleading_s, "s", "0"))
        rows.append((f"{minutes}: {kind} availability", 100 * figures.availability, "%", "-"))
        rows.append(
            (f"{minutes}: {kind} time to alert p50", figures.alert_p50_s, "s", figures.alert_summary())
        )
    for node, growth_mb in result.rss_growth_mb.items():
        rows.append((f"{minutes}: RSS growth of {node} (last incarnation)", growth_mb, "MB", "~0"))
    return rows


def rows(
    duration_s: float = BENCH_DURATION_S, seed: int = BENCH_SEED, output: pathlib.Path | None = None
) -> list[Row]:
    domain_id = int(os.environ.get("ROS_DOMAIN_ID", "66"))
    config = CampaignConfig(
        seed=seed, duration_s=duration_s, output_dir=output, domain_id=domain_id, serial=True, hosts=True
    )
    result = run_campaign(config)
    print(result.report(), file=sys.stderr)
    return result_rows(result)


if __name__ == "__main__":
    sys.exit(bench_main(__doc__, rows))
