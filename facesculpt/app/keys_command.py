"""`facesculpt keys generate`: CURVE keypairs for a graph across hosts (docs/security.md)."""

from __future__ import annotations

from facesculpt.runtime.security import SERVER_KEY_NAME, SecurityError, generate_keypair


def register(sub) -> None:
    p = sub.add_parser("keys", help="CURVE keys for graphs across hosts")
    ksub = p.add_subparsers(dest="keys_command", metavar="generate", required=True)
    q = ksub.add_parser("generate", help="write a keypair NAME.key (public) and NAME.key_secret into DIR")
    q.add_argument("dir", help="keys directory (created if needed)")
    q.add_argument("--name", default=SERVER_KEY_NAME,
                   help=f"key name (default {SERVER_KEY_NAME!r}: the graph's server keypair; "
                        f"give a host's name for a client keypair)")
    q.set_defaults(func=cmd_keys_generate)


def cmd_keys_generate(args) -> int:
    try:
        public, secret = generate_keypair(args.dir, args.name)
    except SecurityError as exc:
        raise ValueError(str(exc)) from None
    print(f"public key: {public}\nsecret key: {secret} (keep it private; copy it only to hosts of the graph)")
    return 0
