"""A throwaway certificate authority and TLS server certificate for the fake Spot.

The real robot presents a certificate for ``*.spot.robot`` signed by the Boston Dynamics root CA
that ships with ``bosdyn-client``; the client checks it against the *authority* names
(``auth.spot.robot``, ``api.spot.robot`` ...), not the IP address it dials. The fake does the same
with a CA generated at test time (EC P-256 keys: milliseconds to make), so the unmodified client
runs its normal TLS verification against it; only the CA file and the port differ.
"""

from __future__ import annotations

import datetime
import ipaddress
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

# Every authority the fake's directory lists, plus the four the client bootstraps without it.
SPOT_AUTHORITIES = ("*.spot.robot", "api.spot.robot", "auth.spot.robot", "id.spot.robot",
                    "payload-registration.spot.robot")


@dataclass(frozen=True)
class TestPKI:
    """Paths of a generated CA certificate and a server key pair signed by it (PEM files)."""

    __test__ = False  # not a pytest test class

    ca_cert: Path
    server_cert: Path
    server_key: Path

    def server_credentials(self) -> tuple[bytes, bytes]:
        """(private key, certificate chain) as bytes, for ``grpc.ssl_server_credentials``."""
        return self.server_key.read_bytes(), self.server_cert.read_bytes()


def _name(common_name: str):
    from cryptography.x509.oid import NameOID
    from cryptography import x509

    return x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, "HELIOS fake Spot (test only)"),
                      x509.NameAttribute(NameOID.COMMON_NAME, common_name)])


def make_test_pki(directory: str | os.PathLike, dns_names: Sequence[str] = SPOT_AUTHORITIES,
                  valid_days: int = 2) -> TestPKI:
    """Write ``ca.pem``, ``server.pem`` and ``server.key`` into ``directory``.

    ``dns_names`` become the server certificate's subjectAltNames (a wrong list makes a server
    the client must refuse). The CA key is never written to disk.
    """
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID

    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    now = datetime.datetime.now(datetime.timezone.utc)
    start, end = now - datetime.timedelta(hours=1), now + datetime.timedelta(days=valid_days)

    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = _name("HELIOS test CA")
    ca_cert = (x509.CertificateBuilder().subject_name(ca_name).issuer_name(ca_name)
               .public_key(ca_key.public_key()).serial_number(x509.random_serial_number())
               .not_valid_before(start).not_valid_after(end)
               .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
               .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                                            content_commitment=False, key_encipherment=False,
                                            data_encipherment=False, key_agreement=False,
                                            encipher_only=False, decipher_only=False), critical=True)
               .sign(ca_key, hashes.SHA256()))

    key = ec.generate_private_key(ec.SECP256R1())
    sans: list = [x509.DNSName(n) for n in dns_names]
    sans.append(x509.IPAddress(ipaddress.ip_address("127.0.0.1")))
    cert = (x509.CertificateBuilder().subject_name(_name(dns_names[0] if dns_names else "fake-spot"))
            .issuer_name(ca_name).public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(start).not_valid_after(end)
            .add_extension(x509.SubjectAlternativeName(sans), critical=False)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
            .sign(ca_key, hashes.SHA256()))

    pki = TestPKI(out / "ca.pem", out / "server.pem", out / "server.key")
    pki.ca_cert.write_bytes(ca_cert.public_bytes(serialization.Encoding.PEM))
    pki.server_cert.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    pki.server_key.write_bytes(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                                 serialization.NoEncryption()))
    os.chmod(pki.server_key, 0o600)
    return pki
