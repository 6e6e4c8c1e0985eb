"""`ins-hil keygen`: write a MAVLink 2 signing key file (mode 0600) and print how to use it.

The key file holds one random passphrase; the 32-byte signing key is its SHA-256, the way MAVProxy
(``signing key PASSPHRASE``) and QGroundControl (its MAVLink signing key field) turn a passphrase into a
key, so the same text goes to the gateway (``signing_key_file``) and to the ground station.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

NAME = "keygen"
HELP = "write a MAVLink signing key file (mode 0600) and print the config lines and ground-station set-up"
DESCRIPTION = (
    "Write a new random MAVLink 2 signing passphrase to FILE (default signing.key; created with mode 0600, never "
    "overwritten without --force) and print the [[outputs]] line that signs an output with it "
    "(signing_key_file), the same key as 64 hex digits (for signing_key of a MAVLink input or for pymavlink), and "
    "how to give it to MAVProxy and QGroundControl. A signed output rejects every unsigned message."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", nargs="?", type=Path, default=Path("signing.key"), help="the key file (default signing.key)")
    p.add_argument("--force", action="store_true", help="replace an existing file")


def passphrase() -> str:
    """A new random passphrase: 43 URL-safe base64 characters (256 bits), one word of printable ASCII."""
    import secrets

    return secrets.token_urlsafe(32)


def write_key_file(path: Path, text: str, force: bool = False) -> None:
    """Write ``text`` + newline to ``path`` created with mode 0600 (an existing file: FileExistsError unless
    ``force``; it is then replaced by a new 0600 file, so an old file's wider mode is not kept)."""
    import os

    tmp = path.with_name(path.name + ".tmp") if force else path
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0)
    if force and tmp.exists():
        tmp.unlink()
    fd = os.open(tmp, flags, 0o600)
    try:
        os.write(fd, (text + "\n").encode("ascii"))
    finally:
        os.close(fd)
    if force:
        try:
            os.replace(tmp, path)
        except OSError:
            tmp.unlink()  # no copy of the secret left beside a file that could not be replaced
            raise


def run(args: argparse.Namespace) -> int:
    import hashlib

    from ins_hil.commands._outputs import out_file

    path: Path = args.file
    out_file(path, "")  # a folder, a path under a file: one line before anything is written
    if not path.parent.is_dir():
        print(f"ins-hil keygen: {path}: no folder {path.parent} (create it first)", file=sys.stderr)
        return 2
    secret = passphrase()
    try:
        write_key_file(path, secret, args.force)
    except FileExistsError:
        print(f"ins-hil keygen: {path} exists (give --force to replace it)", file=sys.stderr)
        return 2
    key_hex = hashlib.sha256(secret.encode("ascii")).hexdigest()
    where = path.resolve()
    print(f"wrote the signing key file {where} (mode 0600). Keep it secret: whoever has it can command the gateway.")
    print()
    print("Gateway config: sign a MAVLink output (every unsigned message to it is then rejected):")
    print()
    print("  [[outputs]]")
    print('  name = "gcs"')
    print(f'  signing_key_file = "{where}"')
    print()
    print("The same key as 64 hex digits (a MAVLink input's signing_key, or pymavlink's mav.setup_signing):")
    print(f'  signing_key = "{key_hex}"')
    print()
    print("Ground station (the same passphrase; never send it over an unsigned link):")
    print(f"  MAVProxy:       module load signing, then: signing key {secret}")
    print(f"                  (or a line '<device> {secret}' in ~/.mavproxy/signing.keys)")
    print(f"  QGroundControl: Application Settings > Telemetry > MAVLink 2 Signing > Key: {secret}")
    print("                  (not 'Send to Vehicle', nor MAVProxy's 'signing setup': the gateway's key is its file)")
    print(f'  pymavlink:      mav.setup_signing(bytes.fromhex("{key_hex}"), sign_outgoing=True)')
    return 0
