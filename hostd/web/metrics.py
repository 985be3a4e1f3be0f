"""``/metrics`` in Prometheus text format, collected from the store and the daemon at scrape time.

- ``hostd_jobs{state}``                               jobs per state (gauge)
- ``hostd_prints_total{result}``                      jobs that ended: done, failed, cancelled,
  interrupted (counted from the store's events, so a requeue never takes one back);
  cancelled counts prints that had started, not jobs cancelled in the queue
- ``hostd_temperature_celsius{printer,heater}``       and ``hostd_temperature_target_celsius``
- ``hostd_printer_up{printer,state}``                 1 for the printer's current state
- ``hostd_printers_waiting_for_person``              printers that start nothing until a
  person says their bed is clear (after every print unless the profile clears it itself)
- ``hostd_serial_lines_sent_total{printer}``, ``hostd_serial_resends_total{printer}``
- ``hostd_planner_starvation_seconds_total{printer}`` time the printer's move planner ran
  dry between moves (known for the built-in simulator only; a real Marlin does not say)
- ``hostd_plan_duration_seconds``                     histogram of plan durations (planned jobs)
- ``hostd_problem{kind}``                             1 while it keeps the node from taking work:
  disk_full (job database), share (cannot be written), stuck (the run loop), node_id (another
  hostd uses it), damaged (job database replaced, printers held)
- ``hostd_drop_folder_files{state}``                  inputs in the drop folder that are no job
  yet: copying, waiting
"""

import re

from flask import Blueprint, Response
from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, HistogramMetricFamily
from prometheus_client.exposition import CONTENT_TYPE_LATEST

from hostd import jobs as J
from hostd.web.api import view
from hostd.web.view import PAGE_STATES

bp = Blueprint("metrics", __name__)

PLAN_BUCKETS_S = (1, 2, 5, 10, 30, 60, 120, 300, 600)
_PLANNED = re.compile(r"planned in ([0-9.]+) s")


def plan_durations(store, limit=1000):
    """Seconds of the last ``limit`` plans, from the jobs' ``planned in N s`` events."""
    rows = store.db.execute("SELECT message FROM events WHERE kind = ? AND message LIKE "
                            "'planned in %' ORDER BY id DESC LIMIT ?", (J.READY, int(limit)))
    out = []
    for (message,) in rows:
        m = _PLANNED.match(message or "")
        if m:
            out.append(float(m.group(1)))
    return out


class _Collector:
    def __init__(self, v):
        self.v = v

    def collect(self):
        v = self.v
        counts = v.counts()
        jobs = GaugeMetricFamily("hostd_jobs", "Jobs in each state", labels=["state"])
        for state in J.STATES:
            jobs.add_metric([state], counts.get(state, 0))
        yield jobs
        prints = CounterMetricFamily("hostd_prints", "Finished jobs by result", labels=["result"])
        ended = v.endings()
        for state in J.FINISHED:
            prints.add_metric([state], ended.get(state, 0))
        yield prints

        temp = GaugeMetricFamily("hostd_temperature_celsius", "Heater temperature",
                                 labels=["printer", "heater"])
        target = GaugeMetricFamily("hostd_temperature_target_celsius", "Heater target",
                                   labels=["printer", "heater"])
        up = GaugeMetricFamily("hostd_printer_state", "1 for the printer's current state",
                               labels=["printer", "state"])
        lines = CounterMetricFamily("hostd_serial_lines_sent", "Lines sent to the printer",
                                    labels=["printer"])
        resends = CounterMetricFamily("hostd_serial_resends", "Resend requests by the printer",
                                      labels=["printer"])
        starve = CounterMetricFamily("hostd_planner_starvation_seconds",
                                     "Seconds the printer's move planner ran dry between moves",
                                     labels=["printer"])
        printers = v.printers()
        for p in printers:
            for heater, t in p["temperatures"].items():
                if t.get("current") is not None:
                    temp.add_metric([p["name"], heater], t["current"])
                if t.get("target") is not None:
                    target.add_metric([p["name"], heater], t["target"])
            for state in PAGE_STATES:
                up.add_metric([p["name"], state], 1.0 if p["state"] == state else 0.0)
            if p["lines_sent"] is not None:
                lines.add_metric([p["name"]], p["lines_sent"])
                resends.add_metric([p["name"]], p["resends"] or 0)
            if p["starvation_s"] is not None:
                starve.add_metric([p["name"]], p["starvation_s"])
        waiting = GaugeMetricFamily("hostd_printers_waiting_for_person", "Printers that start "
                                    "nothing until a person says their bed is clear")
        waiting.add_metric([], sum(1 for p in printers if p["waiting_for_person"]))
        yield from (temp, target, up, lines, resends, starve, waiting)

        if v.daemon is not None:
            from hostd.outages import PROBLEMS
            now = v.daemon.problems()
            problem = GaugeMetricFamily("hostd_problem", "1 while it keeps the node from "
                                        "taking work", labels=["kind"])
            for kind in PROBLEMS:
                problem.add_metric([kind], 1.0 if kind in now else 0.0)
            dropped = GaugeMetricFamily("hostd_drop_folder_files", "Inputs in the drop folder "
                                        "that are no job yet", labels=["state"])
            files = v.drop_folder()
            for state, complete in (("copying", False), ("waiting", True)):
                dropped.add_metric([state], sum(1 for f in files if f["complete"] == complete))
            yield from (problem, dropped)

        durations = plan_durations(v.store)
        buckets = [(str(float(b)), sum(1 for d in durations if d <= b)) for b in PLAN_BUCKETS_S]
        buckets.append(("+Inf", len(durations)))
        yield HistogramMetricFamily("hostd_plan_duration_seconds", "Plan durations",
                                    buckets=buckets, sum_value=sum(durations))


def render(v):
    registry = CollectorRegistry(auto_describe=False)
    registry.register(_Collector(v))
    return generate_latest(registry)


@bp.get("/metrics")
def metrics():
    return Response(render(view()), content_type=CONTENT_TYPE_LATEST)
