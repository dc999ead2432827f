"""Authenticated, encrypted links between the graph's processes (ZeroMQ CURVE).

Off by default (a graph on one machine talks over loopback and ipc sockets).
Turned on by a keys directory, named by ``$FACESCULPT_KEYS`` or by the launch
file's ``security:`` block. Who is the CURVE server of each socket:

* every publisher **binds** (XPUB): it is a CURVE *server* with the graph's
  server keypair, and its authenticator (ZAP) admits only clients whose public
  key is in the keys directory -- a stranger subscriber receives nothing;
* every subscriber **connects** (SUB): it is a CURVE *client* that requires the
  peer to prove the graph's server key -- a stranger's publisher (which lacks
  the graph's secret) never completes the handshake, so its messages are never
  received, even if its endpoint were known;
* the master binds (ROUTER) as a server like a publisher, and nodes talk to it
  as clients -- a stranger cannot register a fake publisher.

Keys directory (``facesculpt keys generate DIR --name NAME`` writes
``NAME.key`` (public) and ``NAME.key_secret`` (public + secret), z85 text)::

    keys/graph.key_secret   the graph's server keypair: every trusted host needs it
    keys/graph.key          ... and its public half
    keys/*.key              public keys of the clients allowed in (graph.key included)
    keys/HOST.key_secret    a client keypair (optional; default: the graph's own)

No sockets are opened here: these helpers configure sockets others own.
"""

from __future__ import annotations

import ipaddress
import os
from dataclasses import dataclass
from pathlib import Path

import zmq
import zmq.auth

SERVER_KEY_NAME = "graph"
ENV_KEYS = "FACESCULPT_KEYS"
ENV_SERVER = "FACESCULPT_SERVER_KEY"
ENV_CLIENT = "FACESCULPT_CLIENT_KEY"


class SecurityError(ValueError):
    """A keys directory or key file that cannot be used; the message names it."""


def generate_keypair(directory: str | os.PathLike, name: str) -> tuple[Path, Path]:
    """Write ``NAME.key`` (public) and ``NAME.key_secret`` (secret) in ``directory``
    (created if needed; the secret file is made readable by its owner only)."""
    directory = Path(directory)
    if not name or "/" in name or name.startswith("."):
        raise SecurityError(f"bad key name {name!r}")
    directory.mkdir(parents=True, exist_ok=True)
    public, secret = directory / f"{name}.key", directory / f"{name}.key_secret"
    if public.exists() or secret.exists():
        raise SecurityError(f"{public} or {secret} already exists: remove it first or choose another --name")
    pub_file, sec_file = zmq.auth.create_certificates(directory, name)
    os.chmod(sec_file, 0o600)
    return Path(pub_file), Path(sec_file)


def load_keypair(path: str | os.PathLike) -> tuple[bytes, bytes]:
    """(public, secret) z85 keys from a ``.key_secret`` file."""
    path = Path(path)
    if not path.is_file():
        raise SecurityError(f"key file {path} not found (make one with `facesculpt keys generate`)")
    try:
        public, secret = zmq.auth.load_certificate(path)
    except Exception as exc:  # pyzmq raises ValueError/OSError for bad files
        raise SecurityError(f"key file {path} is not a ZeroMQ certificate: {exc}") from None
    if secret is None:
        raise SecurityError(f"key file {path} has no secret key (use the .key_secret file)")
    return public, secret


@dataclass
class Security:
    """The keys one process uses: the graph's server keypair (to bind) and a client keypair
    (to connect), and the directory of authorised client public keys."""

    keys_dir: Path
    server_public: bytes
    server_secret: bytes
    client_public: bytes
    client_secret: bytes

    @classmethod
    def from_dir(cls, keys_dir: str | os.PathLike, server: str = SERVER_KEY_NAME,
                 client: str | None = None) -> Security:
        keys_dir = Path(keys_dir).expanduser().resolve()
        if not keys_dir.is_dir():
            raise SecurityError(f"keys directory {keys_dir} not found (make one with `facesculpt keys generate`)")
        server_public, server_secret = load_keypair(keys_dir / f"{server}.key_secret")
        client_public, client_secret = (load_keypair(keys_dir / f"{client}.key_secret") if client
                                        else (server_public, server_secret))
        if not (keys_dir / f"{(client or server)}.key").is_file():
            raise SecurityError(f"{keys_dir}: the client key {(client or server)}.key is not authorised "
                                f"(its public .key file must be in the keys directory)")
        return cls(keys_dir, server_public, server_secret, client_public, client_secret)

    @classmethod
    def from_env(cls, environ=os.environ) -> Security | None:
        """From ``$FACESCULPT_KEYS`` (+ ``$FACESCULPT_SERVER_KEY``, ``$FACESCULPT_CLIENT_KEY`` names); None when unset."""
        keys = environ.get(ENV_KEYS)
        if not keys:
            return None
        return cls.from_dir(keys, environ.get(ENV_SERVER) or SERVER_KEY_NAME, environ.get(ENV_CLIENT) or None)

    # -- configuring sockets --------------------------------------------------------------------
    def server_socket(self, sock: zmq.Socket) -> None:
        """Make a socket that binds a CURVE server (call before bind)."""
        sock.curve_secretkey = self.server_secret
        sock.curve_publickey = self.server_public
        sock.curve_server = True

    def client_socket(self, sock: zmq.Socket) -> None:
        """Make a socket that connects a CURVE client of the graph's server key (call before connect)."""
        sock.curve_secretkey = self.client_secret
        sock.curve_publickey = self.client_public
        sock.curve_serverkey = self.server_public

    def start_authenticator(self, ctx: zmq.Context):
        """Start the ZAP handler of ``ctx``: only clients whose public key is in the keys directory get in."""
        from zmq.auth.thread import ThreadAuthenticator

        auth = ThreadAuthenticator(ctx, log=None)
        auth.start()
        auth.configure_curve(domain="*", location=str(self.keys_dir))
        return auth


def env_for(keys_dir: str | os.PathLike | None, server: str | None = None, client: str | None = None) -> dict:
    """Environment variables that give a child process these keys (empty when security is off)."""
    if not keys_dir:
        return {}
    env = {ENV_KEYS: str(Path(keys_dir).expanduser().resolve())}
    if server:
        env[ENV_SERVER] = server
    if client:
        env[ENV_CLIENT] = client
    return env


# -- secure by default ----------------------------------------------------------------------------
ENV_INSECURE = "FACESCULPT_INSECURE"


def is_loopback(address: str) -> bool:
    """Whether a ZeroMQ endpoint or a bare host (``tcp://127.0.0.1:5555``, ``ipc://...``,
    ``0.0.0.0``, ``localhost``) stays on this machine. ``*`` and ``0.0.0.0`` bind every interface."""
    if address.startswith(("ipc://", "inproc://")):
        return True
    host = address.split("://", 1)[-1]
    if host.startswith("["):                      # tcp://[::1]:5555
        host = host[1:host.find("]")]
    elif host.count(":") == 1:                    # tcp://host:port
        host = host.rsplit(":", 1)[0]
    if host in ("localhost", "::1"):
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False                              # a host name or *: reachable from the network


def insecure_allowed(environ=os.environ) -> bool:
    """``$FACESCULPT_INSECURE`` is set to 1/true/yes: the user accepts a graph without keys on the network."""
    return environ.get(ENV_INSECURE, "").strip().lower() in ("1", "true", "yes")


def check_exposure(what: str, address: str, security: Security | None, insecure: bool) -> str | None:
    """Refuse to expose ``what`` (e.g. "the master", "node camera's publishers") on a non-loopback
    ``address`` without CURVE keys: anyone on the network could read the camera stream of a
    person's face and write fake input or models. With ``insecure`` the binding goes ahead and
    the returned warning line says what is exposed; None when nothing is exposed."""
    if security is not None or is_loopback(address):
        return None
    if not insecure:
        raise SecurityError(
            f"refusing to expose {what} on {address} without CURVE keys: anyone on that network could read "
            f"the camera stream and send input; add a security: block to the launch file (docs/security.md), "
            f"or set insecure: true (or {ENV_INSECURE}=1) to allow it")
    return (f"insecure: {what} on {address} is open to anyone on that network (no CURVE keys): "
            f"camera frames, faces and input events can be read and forged")
