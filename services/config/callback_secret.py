"""How `BFIELDS_CALLBACK_SECRET` becomes the HMAC key of the callback signatures.

Two forms are accepted, and both give one key (bytes) used by every signature header:

- ``whsec_<base64>``: the Standard Webhooks form (standardwebhooks.com); the key is the
  base64-decoded bytes after the prefix (padding optional), exactly as a Standard Webhooks
  library decodes the same string, so receiver and sender configure the same text;
- anything else (the form every release before this one took): the key is the secret's UTF-8
  bytes. A receiver's library is given ``whsec_`` + base64(those bytes) (`as_whsec`,
  ``bfields-service callback-secret``), or the bytes themselves.

Why here, in `config`: the settings check a secret when they load (a malformed ``whsec_`` value
is refused at start, not at the first callback) and the signer derives its key from it; both
call `signing_key`, the one place the rule is written.
"""

from __future__ import annotations

import base64
import binascii
import secrets

WHSEC_PREFIX = "whsec_"
#: Random bytes in a secret that `new_secret` makes (the spec advises 24 to 64).
NEW_SECRET_BYTES = 32


def signing_key(secret: str) -> bytes:
    """The HMAC key that `secret` (a ``whsec_`` string or a raw one) stands for; ValueError naming
    the setting and the fix when a ``whsec_`` value is not base64 or decodes to nothing."""
    if not secret:
        raise ValueError("BFIELDS_CALLBACK_SECRET is empty: unset it, or give a secret")
    if not secret.startswith(WHSEC_PREFIX):
        return secret.encode("utf-8")
    encoded = secret[len(WHSEC_PREFIX) :]
    try:
        key = base64.b64decode(encoded + "=" * (-len(encoded) % 4), validate=True)
    except binascii.Error:
        raise ValueError(
            "BFIELDS_CALLBACK_SECRET starts with 'whsec_' but the rest is not base64: give "
            "'whsec_' + the base64 of the key (`bfields-service callback-secret --new` makes one)"
        ) from None
    if not key:
        raise ValueError("BFIELDS_CALLBACK_SECRET is 'whsec_' with no key after it")
    return key


def as_whsec(secret: str) -> str:
    """The ``whsec_`` form of `secret`: what a receiver gives its Standard Webhooks library (the
    same string back when `secret` is already in that form, up to base64 padding)."""
    return WHSEC_PREFIX + base64.b64encode(signing_key(secret)).decode("ascii")


def new_secret() -> str:
    """A fresh random secret in the ``whsec_`` form."""
    return WHSEC_PREFIX + base64.b64encode(secrets.token_bytes(NEW_SECRET_BYTES)).decode("ascii")
