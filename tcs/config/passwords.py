"""Salted password hashes for the ``[[users]]`` table of a hardware file.

Format: ``pbkdf2_sha256$<iterations>$<salt, base64>$<hash, base64>`` — PBKDF2-HMAC-SHA256 from
the standard library, a random 16-byte salt per user. The hardware file never holds a
plaintext password; ``tcs-passwd`` prints a hash to paste into it. Verification is constant
time. Used by the configuration loader (format check) and the TPL2 server (login).
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import os

SCHEME = "pbkdf2_sha256"
DEFAULT_ITERATIONS = 120_000


def hash_password(password: str, *, iterations: int = DEFAULT_ITERATIONS, salt: bytes | None = None) -> str:
    """Return the storable hash of ``password`` with a fresh random salt."""
    salt = os.urandom(16) if salt is None else salt
    digest = hashlib.pbkdf2_hmac("sha256", password.encode("utf-8"), salt, iterations)
    b64 = lambda b: base64.b64encode(b).decode("ascii")  # noqa: E731
    return f"{SCHEME}${iterations}${b64(salt)}${b64(digest)}"


def check_format(stored: str) -> str | None:
    """Return why ``stored`` is not a usable hash, or ``None`` when it is."""
    parts = stored.split("$")
    if len(parts) != 4 or parts[0] != SCHEME:
        return f"must be a salted hash '{SCHEME}$<iterations>$<salt>$<hash>' (make one with tcs-passwd), never a plaintext password"
    try:
        if int(parts[1]) < 1000:
            return "hash iteration count below 1000 is too weak"
        base64.b64decode(parts[2], validate=True)
        base64.b64decode(parts[3], validate=True)
    except ValueError:
        return "malformed hash (bad iteration count or base64)"
    return None


def verify_password(password: str, stored: str) -> bool:
    """True when ``password`` matches ``stored`` (a hash made by :func:`hash_password`)."""
    if check_format(stored) is not None:
        return False
    _, iterations, salt, digest = stored.split("$")
    candidate = hashlib.pbkdf2_hmac("sha256", password.encode("utf-8"), base64.b64decode(salt), int(iterations))
    return hmac.compare_digest(candidate, base64.b64decode(digest))
