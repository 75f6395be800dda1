"""The ground station: live monitor, fleet commands, recorder, replay and plots (``docs/gcs.md``).

* :mod:`.mavlink_state` / :mod:`.mavlink_listener` — what the autopilots say on the GCS link
  (UDP 14550): per-system heartbeat, mode, armed, battery, altitude, speed and message loss;
* :mod:`.zenoh_listener` — what the agents publish under ``bf/<fleet>/**`` and their liveliness;
* :mod:`.monitor` — both folded into one snapshot per vehicle with alarms, and its rich table;
* :mod:`.commands` — arm, takeoff, land (MAVLink), start, hold (Zenoh), stop (both);
* :mod:`.record` / :mod:`.replay` — MCAP logs of every sample and MAVLink frame;
* :mod:`.analysis` / :mod:`.plot` — series and figures from a recording.

The command line is ``groundstation/gcs_cli.py`` (``bearingflock gcs ...``).
"""
