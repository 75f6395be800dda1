"""``bearingflock keys``: the fleet CA, certificates and MAVLink signing keys on disk (issue 24)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from cryptography import x509
from cryptography.x509.oid import NameOID

from messages.fleetkeys import (
    KeyStoreError,
    describe,
    init_fleet,
    issue_vehicle,
    load_signing_key,
    signing_key_path,
)
from onboard.daemon.config import ConfigError, load_fleet

ROOT = Path(__file__).resolve().parents[2]


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "groundstation.cli", "keys", *args],
        capture_output=True, text=True, timeout=60, cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )  # fmt: skip


def _cert(path: Path) -> x509.Certificate:
    return x509.load_pem_x509_certificate(path.read_bytes())


def test_init_creates_ca_vehicles_gcs_and_signing_keys_mode_0600(tmp_path):
    d = tmp_path / "keys"
    written = init_fleet(d, "alpha", 3)
    names = sorted(p.name for p in written)
    assert names == sorted(
        ["ca.crt", "ca.key", "gcs.crt", "gcs.key", "sim.crt", "sim.key"]
        + [f"vehicle-{i}.{e}" for i in range(3) for e in ("crt", "key")]
        + [f"mavlink-vehicle-{i}.key" for i in range(3)]
    )
    for p in d.iterdir():
        assert p.stat().st_mode & 0o777 == 0o600, p
    ca = _cert(d / "ca.crt")
    for i in range(3):
        cert = _cert(d / f"vehicle-{i}.crt")
        cn = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value
        assert cn == f"alpha-vehicle-{i}"
        cert.verify_directly_issued_by(ca)  # raises if the CA did not sign it
    keys = {load_signing_key(d, i) for i in range(3)}
    assert len(keys) == 3 and all(len(k) == 32 for k in keys)  # one key per vehicle link


def test_init_never_overwrites_without_force(tmp_path):
    init_fleet(tmp_path, "alpha", 2)
    before = (tmp_path / "ca.key").read_bytes()
    with pytest.raises(KeyStoreError, match="exists"):
        init_fleet(tmp_path, "alpha", 2)
    assert (tmp_path / "ca.key").read_bytes() == before
    init_fleet(tmp_path, "alpha", 2, force=True)
    assert (tmp_path / "ca.key").read_bytes() != before
    assert (tmp_path / "ca.key").stat().st_mode & 0o777 == 0o600


def test_issue_adds_a_vehicle_and_needs_the_ca_key(tmp_path):
    init_fleet(tmp_path, "beta", 2)
    ca_key = tmp_path / "ca.key"
    offline = tmp_path.parent / f"{tmp_path.name}-ca.key"
    ca_key.rename(offline)  # kept offline
    with pytest.raises(KeyStoreError, match=r"ca\.key: missing"):
        issue_vehicle(tmp_path, 2)
    offline.rename(ca_key)
    issue_vehicle(tmp_path, 2)
    cert = _cert(tmp_path / "vehicle-2.crt")
    assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == "beta-vehicle-2"
    cert.verify_directly_issued_by(_cert(tmp_path / "ca.crt"))
    assert signing_key_path(tmp_path, 2).stat().st_mode & 0o777 == 0o600
    with pytest.raises(KeyStoreError, match="exists"):
        issue_vehicle(tmp_path, 2)


def test_show_prints_no_secret_and_flags_problems(tmp_path):
    init_fleet(tmp_path, "alpha", 2)
    r = _cli("show", str(tmp_path), "--json")
    assert r.returncode == 0, r.stderr
    rows = [json.loads(line) for line in r.stdout.splitlines()]
    assert len(rows) == 12
    secrets = [load_signing_key(tmp_path, i).hex() for i in range(2)]
    for p in tmp_path.glob("*.key"):
        body = p.read_text()
        if "PRIVATE KEY" in body:
            secrets.append(body.splitlines()[1])
    for s in secrets:
        assert s not in r.stdout
    by_file = {row["file"]: row for row in rows}
    assert by_file["vehicle-1.crt"]["vehicle"] == 1
    assert by_file["vehicle-1.crt"]["subject"] == "alpha-vehicle-1"
    assert by_file["vehicle-1.crt"]["expires"].startswith("20")
    assert all(row["problem"] == "" for row in rows)
    # a certificate from another fleet's CA is flagged
    other = tmp_path / "other"
    init_fleet(other, "alpha", 1)
    (tmp_path / "vehicle-1.crt").write_bytes((other / "vehicle-0.crt").read_bytes())
    os.chmod(tmp_path / "vehicle-0.key", 0o644)
    entries = {e.file: e for e in describe(tmp_path)}
    assert entries["vehicle-1.crt"].problem == "signature does not verify against ca.crt"
    assert entries["vehicle-0.key"].problem == "mode is not 0600"


def test_cli_init_refuses_then_forces(tmp_path):
    r = _cli("init", str(tmp_path / "k"), "--fleet", "alpha", "--vehicles", "2")
    assert r.returncode == 0, r.stderr
    r = _cli("init", str(tmp_path / "k"), "--fleet", "alpha", "--vehicles", "2")
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "exists" in r.stderr and "--force" in r.stderr
    r = _cli("init", str(tmp_path / "k"), "--fleet", "alpha", "--vehicles", "2", "--force")
    assert r.returncode == 0, r.stderr
    r = _cli("init", str(tmp_path / "j"), "--fleet", "bad name", "--vehicles", "2")
    assert r.returncode == 2 and "fleet name" in r.stderr


FORMATION = """
[[agent]]
id = 0
position_ned = [0.0, 0.0, -5.0]
[[agent]]
id = 1
position_ned = [4.0, 0.0, -5.0]
[[agent]]
id = 2
position_ned = [2.0, 3.0, -6.0]
"""


def test_fleet_file_security_dir(tmp_path):
    (tmp_path / "formation.toml").write_text(FORMATION)
    fleet_path = tmp_path / "fleet.toml"
    fleet_path.write_text('formation = "formation.toml"\n[security]\ndir = "keys"\n')
    with pytest.raises(ConfigError, match=r"security\.dir: .* is not a directory") as err:
        load_fleet(fleet_path)
    assert "\n" not in str(err.value)
    init_fleet(tmp_path / "keys", "alpha", 2)  # vehicle 2 not issued yet
    fleet = load_fleet(fleet_path)
    assert fleet.signing_key(1) == load_signing_key(tmp_path / "keys", 1)
    with pytest.raises(ConfigError, match=r"mavlink-vehicle-2\.key: missing"):
        fleet.signing_key(2)
    signing_key_path(tmp_path / "keys", 0).write_text("abcd\n")
    with pytest.raises(ConfigError, match="64 hex characters"):
        fleet.signing_key(0)
    fleet_path.write_text('formation = "formation.toml"\n[security]\ndri = "keys"\n')
    with pytest.raises(ConfigError, match="unknown field"):
        load_fleet(fleet_path)
    fleet_path.write_text('formation = "formation.toml"\n')
    assert load_fleet(fleet_path).signing_key(0) is None
