"""One fleet identity on disk: a certificate authority, one certificate per vehicle and one for
the ground station, and the MAVLink 2 signing keys (``bearingflock keys``, docs/flying.md).

Layout of a key directory::

    ca.crt  ca.key                    the fleet CA (ca.key may be kept offline: only
                                      ``keys init`` and ``keys issue`` need it)
    vehicle-<id>.crt  vehicle-<id>.key   vehicle <id>'s identity, CN=<fleet>-vehicle-<id>
    gcs.crt  gcs.key                  the ground station, CN=<fleet>-gcs
    sim.crt  sim.key                  the simulator (rehearsals), CN=<fleet>-sim
    mavlink-vehicle-<id>.key          32-byte MAVLink signing key of vehicle <id>'s autopilot
                                      link (64 hex characters)

One signing key per vehicle link, not one per fleet: an autopilot holds one key, and a vehicle
that is lost or captured then exposes only its own link. The ground station holds every
vehicle's key (it talks to every autopilot); a vehicle's companion computer holds only its own.

Every file is created with mode 0600 and never replaced unless ``force`` is given. Keys are
ECDSA P-256, made with the ``cryptography`` package (OpenSSL underneath: a maintained,
audited implementation rather than hand-rolled X.509).
"""

from __future__ import annotations

import datetime as dt
import ipaddress
import os
import re
import secrets
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

CA_NAME = "ca"
GCS_NAME = "gcs"
SIM_NAME = "sim"
SIGNING_KEY_BYTES = 32
CA_DAYS = 3650
LEAF_DAYS = 365
MAX_VEHICLES = 255
_FLEET = re.compile(r"^[A-Za-z0-9_-]+$")
_VEHICLE = re.compile(r"^(?:mavlink-)?vehicle-(\d+)\.(?:crt|key)$")


class KeyStoreError(ValueError):
    """A key directory that cannot be used; the message names the file and the problem."""


def vehicle_name(vehicle_id: int) -> str:
    """File stem of vehicle ``vehicle_id``'s certificate and key."""
    return f"vehicle-{vehicle_id}"


def signing_key_path(directory: Path, vehicle_id: int) -> Path:
    """Where vehicle ``vehicle_id``'s MAVLink signing key lives."""
    return Path(directory) / f"mavlink-{vehicle_name(vehicle_id)}.key"


def common_name(fleet: str, name: str) -> str:
    """``<fleet>-vehicle-<id>``, ``<fleet>-gcs`` or ``<fleet>-ca``."""
    return f"{fleet}-{name}"


def _write_private(path: Path, data: bytes, force: bool) -> None:
    """Write ``data`` to ``path`` with mode 0600; refuse to replace an existing file."""
    if path.exists() and not force:
        raise KeyStoreError(f"{path}: exists (use --force to replace it)")
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.chmod(tmp, 0o600)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _new_key() -> ec.EllipticCurvePrivateKey:
    return ec.generate_private_key(ec.SECP256R1())


def _key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )


def _name(fleet: str, name: str) -> x509.Name:
    return x509.Name(
        [
            x509.NameAttribute(NameOID.ORGANIZATION_NAME, fleet),
            x509.NameAttribute(NameOID.COMMON_NAME, common_name(fleet, name)),
        ]
    )


def _ca_cert(fleet: str, key: ec.EllipticCurvePrivateKey, now: dt.datetime) -> x509.Certificate:
    name = _name(fleet, CA_NAME)
    return (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - dt.timedelta(minutes=5))
        .not_valid_after(now + dt.timedelta(days=CA_DAYS))
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=True, content_commitment=False, key_encipherment=False,
                data_encipherment=False, key_agreement=False, key_cert_sign=True,
                crl_sign=True, encipher_only=False, decipher_only=False,
            ),
            critical=True,
        )
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), False)
        .sign(key, hashes.SHA256())
    )  # fmt: skip


def _leaf_cert(
    fleet: str,
    name: str,
    key: ec.EllipticCurvePrivateKey,
    ca_key: ec.EllipticCurvePrivateKey,
    ca_cert: x509.Certificate,
    now: dt.datetime,
    days: int,
) -> x509.Certificate:
    cn = common_name(fleet, name)
    san = x509.SubjectAlternativeName(
        [
            x509.DNSName(cn),
            x509.DNSName("localhost"),
            x509.IPAddress(ipaddress.ip_address("127.0.0.1")),
        ]
    )
    return (
        x509.CertificateBuilder()
        .subject_name(_name(fleet, name))
        .issuer_name(ca_cert.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - dt.timedelta(minutes=5))
        .not_valid_after(min(now + dt.timedelta(days=days), ca_cert.not_valid_after_utc))
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(san, critical=False)
        .add_extension(
            x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
            critical=False,
        )
        .add_extension(
            x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), False
        )
        .sign(ca_key, hashes.SHA256())
    )  # fmt: skip


def _check_fleet_name(fleet: str) -> None:
    if not _FLEET.match(fleet):
        raise KeyStoreError(f"fleet name {fleet!r} must be letters, digits, '_' or '-'")


def _issue_leaf(
    directory: Path,
    fleet: str,
    name: str,
    ca_key: ec.EllipticCurvePrivateKey,
    ca_cert: x509.Certificate,
    days: int,
    force: bool,
    now: dt.datetime,
) -> list[Path]:
    key = _new_key()
    cert = _leaf_cert(fleet, name, key, ca_key, ca_cert, now, days)
    key_path, crt_path = directory / f"{name}.key", directory / f"{name}.crt"
    _write_private(key_path, _key_pem(key), force)
    _write_private(crt_path, cert.public_bytes(serialization.Encoding.PEM), force)
    return [crt_path, key_path]


def _issue_signing_key(directory: Path, vehicle_id: int, force: bool) -> Path:
    path = signing_key_path(directory, vehicle_id)
    _write_private(path, secrets.token_bytes(SIGNING_KEY_BYTES).hex().encode() + b"\n", force)
    return path


def _targets(n_vehicles: int) -> list[str]:
    return [CA_NAME, GCS_NAME, SIM_NAME, *(vehicle_name(i) for i in range(n_vehicles))]


def init_fleet(
    directory: str | Path,
    fleet: str,
    n_vehicles: int,
    force: bool = False,
    days: int = LEAF_DAYS,
    now: dt.datetime | None = None,
) -> list[Path]:
    """Create the fleet CA, the ground station's and ``n_vehicles`` vehicles' certificates and
    keys and the vehicles' signing keys in ``directory``; returns the files written.

    Nothing is written if any file exists and ``force`` is false."""
    _check_fleet_name(fleet)
    if not 1 <= n_vehicles <= MAX_VEHICLES:
        raise KeyStoreError(f"--vehicles must be in 1..{MAX_VEHICLES}, got {n_vehicles}")
    if not 1 <= days <= CA_DAYS:
        raise KeyStoreError(f"--days must be in 1..{CA_DAYS}, got {days}")
    d = Path(directory)
    if d.exists() and not d.is_dir():
        raise KeyStoreError(f"{d}: not a directory")
    d.mkdir(parents=True, exist_ok=True, mode=0o700)
    planned = [d / f"{t}.{ext}" for t in _targets(n_vehicles) for ext in ("crt", "key")]
    planned += [signing_key_path(d, i) for i in range(n_vehicles)]
    existing = [p for p in planned if p.exists()]
    if existing and not force:
        raise KeyStoreError(
            f"{existing[0]}: exists ({len(existing)} of the files do; use --force to replace)"
        )
    now = now or dt.datetime.now(dt.timezone.utc)
    ca_key = _new_key()
    ca_cert = _ca_cert(fleet, ca_key, now)
    written = [d / "ca.key", d / "ca.crt"]
    _write_private(written[0], _key_pem(ca_key), force)
    _write_private(written[1], ca_cert.public_bytes(serialization.Encoding.PEM), force)
    written += _issue_leaf(d, fleet, GCS_NAME, ca_key, ca_cert, days, force, now)
    written += _issue_leaf(d, fleet, SIM_NAME, ca_key, ca_cert, days, force, now)
    for i in range(n_vehicles):
        written += _issue_leaf(d, fleet, vehicle_name(i), ca_key, ca_cert, days, force, now)
        written.append(_issue_signing_key(d, i, force))
    return written


def _load_ca(d: Path) -> tuple[ec.EllipticCurvePrivateKey, x509.Certificate]:
    cert = load_certificate(d / "ca.crt")
    key_path = d / "ca.key"
    try:
        key = serialization.load_pem_private_key(key_path.read_bytes(), password=None)
    except FileNotFoundError:
        raise KeyStoreError(
            f"{key_path}: missing (the CA key is needed to issue; bring it back from offline)"
        ) from None
    except (OSError, ValueError, TypeError) as exc:
        raise KeyStoreError(f"{key_path}: not a usable private key ({exc})") from None
    if not isinstance(key, ec.EllipticCurvePrivateKey):
        raise KeyStoreError(f"{key_path}: not an EC private key")
    if key.public_key().public_numbers() != cert.public_key().public_numbers():
        raise KeyStoreError(f"{key_path}: does not match ca.crt")
    return key, cert


def fleet_of(cert: x509.Certificate) -> str:
    """The fleet name a certificate belongs to (its O= attribute)."""
    attrs = cert.subject.get_attributes_for_oid(NameOID.ORGANIZATION_NAME)
    return str(attrs[0].value) if attrs else ""


def issue_vehicle(
    directory: str | Path,
    vehicle_id: int,
    force: bool = False,
    days: int = LEAF_DAYS,
    now: dt.datetime | None = None,
) -> list[Path]:
    """Add (or with ``force`` re-issue) vehicle ``vehicle_id``: certificate, key, signing key."""
    if not 0 <= vehicle_id < MAX_VEHICLES:
        raise KeyStoreError(f"--vehicle must be in 0..{MAX_VEHICLES - 1}, got {vehicle_id}")
    if not 1 <= days <= CA_DAYS:
        raise KeyStoreError(f"--days must be in 1..{CA_DAYS}, got {days}")
    d = Path(directory)
    ca_key, ca_cert = _load_ca(d)
    name = vehicle_name(vehicle_id)
    planned = [d / f"{name}.crt", d / f"{name}.key", signing_key_path(d, vehicle_id)]
    existing = [p for p in planned if p.exists()]
    if existing and not force:
        raise KeyStoreError(f"{existing[0]}: exists (use --force to re-issue)")
    now = now or dt.datetime.now(dt.timezone.utc)
    written = _issue_leaf(d, fleet_of(ca_cert), name, ca_key, ca_cert, days, force, now)
    written.append(_issue_signing_key(d, vehicle_id, force))
    return written


def identity_files(directory: str | Path, name: str) -> tuple[Path, Path, Path]:
    """``(ca.crt, <name>.crt, <name>.key)`` of an identity (``vehicle-<id>``, ``gcs``, ``sim``)
    for Zenoh TLS."""
    d = Path(directory)
    return d / "ca.crt", d / f"{name}.crt", d / f"{name}.key"


def identity_fleet(directory: str | Path) -> str:
    """The fleet name the directory's CA certifies (its O=): the common names' prefix."""
    return fleet_of(load_certificate(Path(directory) / "ca.crt"))


def vehicle_count(directory: str | Path) -> int:
    """1 + the highest vehicle id with a certificate in ``directory`` (0 if none)."""
    ids = [
        int(m.group(1))
        for p in Path(directory).glob("vehicle-*.crt")
        if (m := _VEHICLE.match(p.name))
    ]
    return max(ids) + 1 if ids else 0


def load_certificate(path: Path) -> x509.Certificate:
    """A PEM certificate; :class:`KeyStoreError` if missing or unreadable."""
    try:
        return x509.load_pem_x509_certificate(Path(path).read_bytes())
    except FileNotFoundError:
        raise KeyStoreError(f"{path}: missing") from None
    except (OSError, ValueError) as exc:
        raise KeyStoreError(f"{path}: not a PEM certificate ({exc})") from None


def load_signing_key(directory: str | Path, vehicle_id: int) -> bytes:
    """Vehicle ``vehicle_id``'s 32-byte MAVLink signing key."""
    path = signing_key_path(Path(directory), vehicle_id)
    try:
        text = path.read_bytes().strip()
    except FileNotFoundError:
        raise KeyStoreError(
            f"{path}: missing (bearingflock keys issue {directory} --vehicle {vehicle_id})"
        ) from None
    except OSError as exc:
        raise KeyStoreError(f"{path}: cannot read ({exc.strerror})") from None
    try:
        key = bytes.fromhex(text.decode("ascii"))
    except (UnicodeDecodeError, ValueError):
        key = b""
    if len(key) != SIGNING_KEY_BYTES:
        raise KeyStoreError(f"{path}: must hold {SIGNING_KEY_BYTES} bytes as 64 hex characters")
    return key


def load_signing_keys(directory: str | Path) -> dict[int, bytes]:
    """Every vehicle's signing key in ``directory``, by vehicle id (the ground station's set);
    :class:`KeyStoreError` if there is none or one is malformed."""
    d = Path(directory)
    if not d.is_dir():
        raise KeyStoreError(f"{d}: not a directory")
    ids = sorted(
        int(m.group(1))
        for p in d.iterdir()
        if p.name.startswith("mavlink-") and (m := _VEHICLE.match(p.name))
    )
    if not ids:
        raise KeyStoreError(f"{d}: no mavlink-vehicle-<id>.key (bearingflock keys init)")
    return {i: load_signing_key(d, i) for i in ids}


@dataclass(frozen=True)
class Entry:
    """One certificate or signing key as ``keys show`` prints it (no secrets)."""

    file: str
    kind: str
    subject: str
    vehicle: int | None
    fingerprint: str
    expires: str
    mode: str
    problem: str = ""


def _fingerprint(data: bytes) -> str:
    digest = hashes.Hash(hashes.SHA256())
    digest.update(data)
    return digest.finalize().hex()[:32]


def describe(directory: str | Path, now: dt.datetime | None = None) -> list[Entry]:
    """What a key directory holds: certificates (subject, SHA-256 fingerprint, expiry, whether
    the fleet CA signed it) and signing keys (SHA-256 of the key, never the key itself)."""
    d = Path(directory)
    if not d.is_dir():
        raise KeyStoreError(f"{d}: not a directory")
    now = now or dt.datetime.now(dt.timezone.utc)
    ca: x509.Certificate | None = None
    if (d / "ca.crt").exists():
        ca = load_certificate(d / "ca.crt")
    out: list[Entry] = []
    for path in sorted(d.iterdir()):
        m = _VEHICLE.match(path.name)
        vehicle = int(m.group(1)) if m else None
        mode = oct(path.stat().st_mode & 0o777)
        problem = "" if mode == "0o600" else "mode is not 0600"
        if path.suffix == ".crt":
            cert = load_certificate(path)
            expires = cert.not_valid_after_utc
            if expires < now:
                problem = "expired"
            elif ca is not None and cert.issuer != ca.subject:
                problem = "not issued by this fleet's CA"
            elif ca is not None and path.name != "ca.crt":
                try:
                    cert.verify_directly_issued_by(ca)
                except (ValueError, TypeError, Exception):  # InvalidSignature and friends
                    problem = "signature does not verify against ca.crt"
            fp = cert.fingerprint(hashes.SHA256()).hex()[:32]
            cn = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
            subject = str(cn[0].value) if cn else cert.subject.rfc4514_string()
            out.append(
                Entry(path.name, "certificate", subject, vehicle, fp, expires.isoformat(), mode,
                      problem)
            )  # fmt: skip
        elif path.name.startswith("mavlink-") and path.suffix == ".key":
            try:
                fp = _fingerprint(load_signing_key(d, vehicle if vehicle is not None else -1))
            except KeyStoreError as exc:
                fp, problem = "", str(exc)
            out.append(Entry(path.name, "signing key", "", vehicle, fp, "", mode, problem))
        elif path.suffix == ".key":
            out.append(Entry(path.name, "private key", "", vehicle, "", "", mode, problem))
    return out
