"""``python -m onboard.daemon --id I --config FLEET.toml``: one vehicle's daemon, lean entry.

The same options as ``bearingflock agent`` (``onboard/daemon/entry.py``) without importing the
rest of the toolkit's command line (issue 27, onboard footprint). As ``groundstation/cli.py``
does for ``agent``, the daemon's environment (one BLAS thread, one MAVLink dialect:
``onboard/daemon/daemon_env.py``) is set before anything imports numpy or pymavlink.
"""

# the daemon's BLAS and MAVLink variables must be set before any import below loads numpy

from __future__ import annotations

import os

from onboard.daemon.daemon_env import DAEMON_SUBCOMMAND, daemon_env_defaults

os.environ.update(daemon_env_defaults([DAEMON_SUBCOMMAND], os.environ))

from onboard.daemon.entry import main

if __name__ == "__main__":
    main()
