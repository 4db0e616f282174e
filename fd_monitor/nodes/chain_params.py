"""The parameters every chain node declares (:data:`COMMON_PARAMS`), and the shared
declarations of the join, detection and fault-verdict parameters some of them add."""

from __future__ import annotations

from fd_monitor.nodes.params import Param
from fd_monitor.nodes.qos import DEFAULT_DEPTH
from fd_monitor.wire.stream import BATCH_PACE, MAX_GAP, MAX_LAG, RESTART_AFTER, STAMP_HORIZON
from fd_monitor.wire.stream import GAP_TIMEOUT as GAP_TIMEOUT_S

__all__ = ["COMMON_PARAMS", "FAULT_PARAMS", "GAP_TIMEOUT", "MAX_GAP_PARAM", "RUNTIME_PARAMS",
           "WARN_SHARE"]

#: The join's hole timeout, of every node that joins plant/u and plant/y.
GAP_TIMEOUT = Param("gap_timeout", GAP_TIMEOUT_S, "s a later sample must have been complete "
                    "before a missing one is declared lost (a hole: restart at the next valid "
                    "sample); absorbs out-of-order publication", low=0.001, high=3600.0)
#: The longest hole bridged, of every node that joins plant/u and plant/y.
MAX_GAP_PARAM = Param("max_gap", MAX_GAP, "lost samples in a row that are bridged: the run "
                      "goes on with its estimates, alarm and isolation memory; a longer hole "
                      "restarts the run (fresh state); 0: every hole restarts", low=0,
                      high=1000000)
#: The per-channel WARN level of every node that detects.
WARN_SHARE = Param("warn_share", 0.8, "WARN when |residual| exceeds this share of its "
                   "threshold", read_only=False, low=0.0, high=1.0)

COMMON_PARAMS = (
    Param("system", "three_tank", "plant file, or the name of a shipped plant"),
    Param("gains", "three_tank_thresholds", "gain file (path or name in config/gains/); "
          "loaded and its certificate re-verified at configure; settable at runtime (a bad "
          "one is refused, the old one keeps running)", read_only=False),
    Param("autostart", True, "configure and activate at start; a lifecycle manager's first "
          "configure then takes over (deactivate, cleanup, configure as asked); false: wait "
          "for lifecycle transitions"),
    Param("hardware_id", "", "hardware_id of the /diagnostics statuses; empty: "
          "<namespace>/<plant> (the plant alone in the root namespace)"),
    Param("stale_timeout", 2.0, "s without input before the input channel turns STALE",
          read_only=False, low=0.01, high=1.0e6),
    Param("diagnostics_period", 1.0, "s between /diagnostics publications",
          read_only=False, low=0.01, high=3600.0),
    Param("log_throttle", 1.0, "s between two log lines about bad input (the others are "
          "counted)", read_only=False, low=0.0, high=3600.0),
    Param("stamp_horizon", STAMP_HORIZON, "samples above the next expected stamp beyond which a "
          "stamp is held as a possible new run, not joined", low=1, high=2**53),
    Param("restart_after", RESTART_AFTER, "s without progress before held stamps (a stream that "
          "restarted lower, or jumped beyond the horizon) become a new run", low=0.001,
          high=3600.0),
    Param("qos_depth", DEFAULT_DEPTH, "history depth of the publishers", low=10,
          high=1000000),
    Param("max_pending", 100000, "samples buffered while waiting for inputs", low=10,
          high=10000000),
    Param("max_lag", MAX_LAG, "s a complete sample may wait since it was received before "
          "the node sheds load: it skips ahead to a recent sample (counted: shed_samples on "
          "/diagnostics); at least gap_timeout; never for a batch (messages with the batch "
          "mark: replay, plant_sim flat out; or by batch_pace); 0.0: never", low=0.0,
          high=3600.0),
    Param("batch_pace", BATCH_PACE, "x real time, for a fast source that cannot mark its "
          "messages as a batch: an unmarked backlog that came faster than this is a batch "
          "too (processed completely); 0.0: only marked messages are a batch", low=0.0,
          high=1.0e9),
)

#: The fault verdict's rule (:class:`~fd_monitor.core.verdict.VerdictRule`), of the nodes
#: that publish ``fd/fault`` (monitor, bias_estimator).
FAULT_PARAMS = (
    Param("fault_confirm", 3, "fault verdict: alarms of a channel within fault_window that "
          "set its fault", low=1, high=100000),
    Param("fault_window", 1.0, "fault verdict: s of plant time over which alarms are counted",
          low=0.0, high=1.0e6),
    Param("fault_clear_after", 5.0, "fault verdict: s of plant time without evidence (alarm, "
          "isolation, significant estimate) after which a fault clears (or ~/reset)",
          low=0.0, high=1.0e6),
)

#: Parameters that take effect when set (the others are read-only).
RUNTIME_PARAMS = ("gains", "stale_timeout", "diagnostics_period", "log_throttle",
                  "warn_share")
