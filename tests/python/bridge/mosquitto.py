"""A real mosquitto broker on a free loopback port, for the bridge tests and soak.

Each broker gets its own config file (listener on 127.0.0.1 only), its own
persistence directory (so a restart keeps sessions and queued messages, as
a production broker would) and, on request, a password file and TLS files.
"""
from __future__ import annotations

import os
import shutil
import socket
import subprocess
import threading
from typing import List, Optional

MOSQUITTO = shutil.which("mosquitto", path=os.environ.get("PATH", "") + ":/usr/sbin:/usr/local/sbin")
MOSQUITTO_PASSWD = shutil.which("mosquitto_passwd", path=os.environ.get("PATH", "") + ":/usr/bin:/usr/sbin")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Mosquitto:
    """``start()`` / ``stop()`` / ``restart()`` a mosquitto on ``port`` (a context manager)."""

    def __init__(self, workdir: str, *, port: Optional[int] = None, users: Optional[dict] = None,
                 tls: Optional[dict] = None, acl: Optional[str] = None, start_timeout: float = 10.0,
                 extra: Optional[List[str]] = None) -> None:
        self.workdir = workdir
        self.port = port or free_port()
        self.start_timeout = start_timeout
        self.proc: Optional[subprocess.Popen] = None
        self.log: List[str] = []
        os.makedirs(os.path.join(workdir, "db"), exist_ok=True)
        lines = [f"listener {self.port} 127.0.0.1",
                 "persistence true", f"persistence_location {workdir}/db/",
                 "log_dest stderr", "log_type error", "log_type warning", "log_type notice",
                 "log_type information", "max_queued_messages 0", "max_inflight_messages 0"]
        if os.geteuid() == 0:   # as root mosquitto would switch to user "mosquitto": no access here
            lines.append("user root")
        if users:
            pw = os.path.join(workdir, "passwd")
            open(pw, "w").close()
            for user, password in users.items():
                subprocess.run([MOSQUITTO_PASSWD, "-b", pw, user, password], check=True)
            lines += ["allow_anonymous false", f"password_file {pw}"]
        else:
            lines += ["allow_anonymous true"]
        if acl is not None:   # mosquitto's acl_file text (anonymous rules first)
            path = os.path.join(workdir, "acl")
            with open(path, "w") as f:
                f.write(acl)
            lines.append(f"acl_file {path}")
        if tls:
            lines += [f"cafile {tls['ca']}", f"certfile {tls['cert']}", f"keyfile {tls['key']}"]
        lines += extra or []   # e.g. a bridge section ("connection ..."): last, as mosquitto wants
        self.conf = os.path.join(workdir, "mosquitto.conf")
        with open(self.conf, "w") as f:
            f.write("\n".join(lines) + "\n")

    def start(self) -> "Mosquitto":
        ready = threading.Event()
        self.proc = subprocess.Popen([MOSQUITTO, "-c", self.conf], stderr=subprocess.PIPE,
                                     stdout=subprocess.DEVNULL, text=True)

        def read(proc: subprocess.Popen) -> None:
            for line in proc.stderr:
                self.log.append(line.rstrip())
                if " running" in line:
                    ready.set()
            ready.set()   # exited

        threading.Thread(target=read, args=(self.proc,), daemon=True).start()
        if not ready.wait(self.start_timeout) or self.proc.poll() is not None:
            tail = "\n".join(self.log[-10:])
            self.stop()
            raise RuntimeError(f"mosquitto did not start on port {self.port}:\n{tail}")
        return self

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.proc = None

    def restart(self) -> None:
        self.stop()
        self.start()

    def __enter__(self) -> "Mosquitto":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def make_tls(workdir: str, host: str = "127.0.0.1") -> dict:
    """A throwaway CA and a server certificate for ``host``, made with ``cryptography``."""
    import datetime
    import ipaddress

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    now = datetime.datetime.now(datetime.timezone.utc)
    valid = {"not_valid_before": now - datetime.timedelta(minutes=5),
                 "not_valid_after": now + datetime.timedelta(days=2)}

    def name(cn: str) -> x509.Name:
        return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])

    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca = (x509.CertificateBuilder().subject_name(name("fap-bridge test CA")).issuer_name(name("fap-bridge test CA"))
          .public_key(ca_key.public_key()).serial_number(x509.random_serial_number())
          .not_valid_before(valid["not_valid_before"]).not_valid_after(valid["not_valid_after"])
          .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
          .sign(ca_key, hashes.SHA256()))
    key = ec.generate_private_key(ec.SECP256R1())
    cert = (x509.CertificateBuilder().subject_name(name(host)).issuer_name(ca.subject)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(valid["not_valid_before"]).not_valid_after(valid["not_valid_after"])
            .add_extension(x509.SubjectAlternativeName([x509.IPAddress(ipaddress.ip_address(host)),
                                                        x509.DNSName("localhost")]), critical=False)
            .sign(ca_key, hashes.SHA256()))
    paths = {n: os.path.join(workdir, f"{n}.pem") for n in ("ca", "cert", "key")}
    with open(paths["ca"], "wb") as f:
        f.write(ca.public_bytes(serialization.Encoding.PEM))
    with open(paths["cert"], "wb") as f:
        f.write(cert.public_bytes(serialization.Encoding.PEM))
    with open(paths["key"], "wb") as f:
        f.write(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.TraditionalOpenSSL,
                                  serialization.NoEncryption()))
    return paths
