"""Zenoh access control of a secured fleet (``[security]``; docs/flying.md).

Zenoh enforces an ACL in the peer that holds it, and peers found by gossip talk directly, so
every process of the fleet loads the same rules and enforces them on what it receives. The
subjects are the certificate common names the fleet CA issued (``bearingflock keys init``):

* ``<fleet>-vehicle-<j>`` may put (and declare liveliness tokens) only under
  ``bf/<fleet>/<j>/**``: its status, peer payloads, command acks, its own camera images;
* ``<fleet>-gcs`` may put fleet commands (``bf/<fleet>/*/command``), formation changes and
  leader drives (``.../command/formation``, ``.../command/leader``) and lockstep steps;
* ``<fleet>-sim`` (rehearsals only: do not give a real fleet ``sim.crt``) may put the
  simulator's clock and each vehicle's virtual camera and truth;
* every subject may subscribe, query liveliness and receive what we publish;
* anything else, including a certificate with another common name, is denied by default.

The daemon still checks that a payload's ``sender`` is the id in its key, so with these rules
the claimed sender is the authenticated one.
"""

from __future__ import annotations

from typing import Any

from messages.command import COMMAND_TOPIC, FORMATION_TOPIC, LEADER_TOPIC
from messages.image import IMAGE_TOPIC
from messages.keys import PREFIX
from messages.sim import CAMERA_TOPIC, TRUTH_TOPIC

READ = ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query", "query"]
WRITE = ["put", "delete", "liveliness_token"]


def fleet_access_control(
    fleet: str, n_vehicles: int, identity_fleet: str | None = None
) -> dict[str, Any]:
    """The ``access_control`` section for a fleet of vehicles ``0..n_vehicles-1`` (module
    docstring), as ``ZenohSettings.extra`` entries. ``fleet`` names the Zenoh keys,
    ``identity_fleet`` the certificates (``keys init --fleet``; default: the same)."""
    root = f"{PREFIX}/{fleet}"
    cn = identity_fleet if identity_fleet is not None else fleet
    rules: list[dict[str, Any]] = [
        {"id": "read", "messages": READ, "flows": ["ingress", "egress"], "permission": "allow",
         "key_exprs": [f"{root}/**"]},
        {"id": "deliver", "messages": [*WRITE, "reply"], "flows": ["egress"],
         "permission": "allow", "key_exprs": [f"{root}/**"]},
        {"id": "gcs_put", "messages": ["put"], "flows": ["ingress"], "permission": "allow",
         "key_exprs": [f"{root}/*/{COMMAND_TOPIC}", f"{root}/*/{FORMATION_TOPIC}",
                       f"{root}/*/{LEADER_TOPIC}", f"{root}/sim/step"]},
        {"id": "sim_put", "messages": ["put"], "flows": ["ingress"], "permission": "allow",
         "key_exprs": [f"{root}/sim/**", f"{root}/*/{CAMERA_TOPIC}", f"{root}/*/{TRUTH_TOPIC}",
                       f"{root}/*/{IMAGE_TOPIC}"]},
    ]  # fmt: skip
    subjects = [
        {"id": "gcs", "cert_common_names": [f"{cn}-gcs"]},
        {"id": "sim", "cert_common_names": [f"{cn}-sim"]},
    ]
    policies = [
        {"rules": ["read", "deliver", "gcs_put"], "subjects": ["gcs"]},
        {"rules": ["read", "deliver", "sim_put"], "subjects": ["sim"]},
    ]
    for j in range(n_vehicles):
        rules.append(
            {"id": f"own_{j}", "messages": WRITE, "flows": ["ingress"], "permission": "allow",
             "key_exprs": [f"{root}/{j}/**"]}
        )  # fmt: skip
        subjects.append({"id": f"vehicle_{j}", "cert_common_names": [f"{cn}-vehicle-{j}"]})
        policies.append({"rules": ["read", "deliver", f"own_{j}"], "subjects": [f"vehicle_{j}"]})
    return {
        "access_control": {
            "enabled": True,
            "default_permission": "deny",
            "rules": rules,
            "subjects": subjects,
            "policies": policies,
        }
    }
