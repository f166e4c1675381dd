"""MAVLink 2 signing: the key file, the signature check we install on pymavlink, and why a frame was refused.

Key file: exactly 32 raw bytes, or 64 hex digits (surrounding whitespace allowed). MAVProxy's
`signing setup PASSPHRASE` uses SHA-256(PASSPHRASE) as the key, so `printf %s PASSPHRASE | sha256sum` gives the
same key in hex. An all-zero key is refused: SETUP_SIGNING uses it to mean "signing off".

pymavlink (2.4.x) records a stream's signature timestamp *before* it checks the signature, so one forged frame
with a far-future timestamp would make every genuine frame of that stream look replayed. `SignatureGuard`
verifies the SHA-256 signature first and only then lets pymavlink apply its timestamp (replay) rules.
"""

from __future__ import annotations

import hashlib
import logging
import re
from pathlib import Path
from typing import Any

from taco_mav.errors import ConfigError

log = logging.getLogger(__name__)

KEY_BYTES = 32
SIGNATURE_LEN = 13  # link id (1) + timestamp (6) + signature (6)
MAGIC_V1, MAGIC_V2 = 0xFE, 0xFD
IFLAG_SIGNED = 0x01
_HEX_KEY = re.compile(rb"^[0-9a-fA-F]{64}$")


def load_key(path: str | Path) -> bytes:
    """The 32-byte key in `path` (raw or hex); ConfigError naming the file when it is missing or malformed."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise ConfigError(f"--signing-key {path}: file not found") from None
    except IsADirectoryError:
        raise ConfigError(f"--signing-key {path}: is a directory, expected a key file") from None
    except OSError as exc:
        raise ConfigError(f"--signing-key {path}: cannot read ({exc.strerror})") from None
    stripped = data.strip()
    if _HEX_KEY.match(stripped):
        key = bytes.fromhex(stripped.decode("ascii"))
    elif len(data) == KEY_BYTES:
        key = data
    else:
        raise ConfigError(f"--signing-key {path}: expected 32 raw bytes or 64 hex digits, got {len(data)} bytes")
    if key == bytes(KEY_BYTES):
        raise ConfigError(f"--signing-key {path}: the all-zero key means 'signing off'; use a random key")
    return key


def key_file(path: str | Path) -> Path:
    """Check a `--signing-key` file up front (the CLI) and return its path."""
    load_key(path)
    return Path(path)


def signature(key: bytes, frame: bytes | bytearray) -> bytes:
    """The 6-byte signature of a signed MAVLink 2 frame: SHA-256(key + frame without its last 6 bytes)[:6]."""
    return hashlib.sha256(key + bytes(frame[:-6])).digest()[:6]


class SignatureGuard:
    """Installed as `mav.check_signature`: signature first, then pymavlink's timestamp rules. `last_reason` says
    why the last signed frame was refused ("bad_signature" or "replay")."""

    def __init__(self, mav: Any, key: bytes) -> None:
        self._pymavlink_check = mav.check_signature
        self.key = key
        self.last_reason = ""
        mav.check_signature = self

    def __call__(self, msgbuf: bytearray, src_system: int, src_component: int) -> bool:
        if len(msgbuf) < SIGNATURE_LEN or signature(self.key, msgbuf) != bytes(msgbuf[-6:]):
            self.last_reason = "bad_signature"
            return False
        if not self._pymavlink_check(msgbuf, src_system, src_component):
            self.last_reason = "replay"
            return False
        return True


def frame_msgid(frame: bytes | bytearray) -> int | None:
    """The message id of a raw MAVLink 1 or 2 frame, or None when the header is incomplete."""
    if len(frame) >= 10 and frame[0] == MAGIC_V2:
        return frame[7] | (frame[8] << 8) | (frame[9] << 16)
    if len(frame) >= 6 and frame[0] == MAGIC_V1:
        return frame[5]
    return None


def frame_is_signed(frame: bytes | bytearray) -> bool:
    """True for a MAVLink 2 frame with the signed incompat flag."""
    return len(frame) >= 3 and frame[0] == MAGIC_V2 and bool(frame[2] & IFLAG_SIGNED)
