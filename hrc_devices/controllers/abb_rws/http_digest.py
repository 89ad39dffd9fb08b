"""HTTP Digest access authentication (RFC 7616, RFC 2617 §3.2): MD5 with ``qop=auth``, pure functions for both sides.

ABB's Robot Web Services 1.0 (IRC5) authenticate every request this way. Server::

    challenge = DigestChallenge(realm, make_nonce(secret, now_mono_ns), opaque)   # 401, WWW-Authenticate
    auth = parse_authorization(request.headers["Authorization"])                 # DigestError if malformed
    verdict = check_authorization(auth, method, uri, credentials, secret, opaque, now_mono_ns, last_nc)
    # verdict.reason is None: accepted; the caller remembers verdict.nc as the nonce's last count

Client::

    challenge = parse_challenge(response.headers["WWW-Authenticate"])
    header = authorization_header(challenge, credentials, method, uri, nc, cnonce)   # nc = 1, 2, 3, ...

The response digest (RFC 2617 eq. 3.2.2.1, ``qop=auth``)::

    HA1 = MD5(username ":" realm ":" password)
    HA2 = MD5(method ":" uri)
    response = MD5(HA1 ":" nonce ":" nc ":" cnonce ":" qop ":" HA2)

A nonce is ``<issued_ns hex>.<HMAC-SHA256(secret, issued_ns) hex>``: the server verifies it without remembering it,
and its age is read from it (on the server's monotonic clock). Replays are refused by the nonce count: a request
is accepted only if its ``nc`` is greater than the last one accepted with that nonce (the caller keeps that one
integer per nonce in use). Every secret-dependent comparison is constant-time (:func:`hmac.compare_digest`).

MD5 Digest protects the password, not the traffic: RWS 1.0 runs over plain HTTP, so anyone on the link reads
and can delay what is sent (the README's threat note: the bridge belongs on a dedicated link).
"""

from __future__ import annotations

import hashlib
import hmac
import re
from dataclasses import dataclass
from typing import Literal

from hrc_contract.errors import HrcError

MAX_HEADER_CHARS = 2048
"""An Authorization or WWW-Authenticate value longer than this is malformed [characters]."""

NONCE_LIFETIME_S = 300.0
"""A nonce older than this is refused as stale (the client retries with the fresh one it is given) [s]."""

_TOKEN = r"[A-Za-z0-9!#$%&'*+.^_`|~-]+"
_PARAM = re.compile(rf'\s*({_TOKEN})\s*=\s*(?:"((?:[^"\\]|\\.)*)"|({_TOKEN}))\s*(?:,|$)')
_NC = re.compile(r"[0-9a-fA-F]{8}")
_CNONCE = re.compile(r"[\x21-\x7e]{1,64}")

Rejection = Literal["bad_user", "bad_realm", "bad_uri", "bad_nonce", "stale", "bad_opaque", "bad_response", "replay"]
"""Why a well-formed Authorization is refused (:func:`check_authorization`)."""


class DigestError(HrcError):
    """A Digest header that does not parse (what was given and what is allowed is in the message)."""


@dataclass(frozen=True)
class Credentials:
    """A user name and password."""

    username: str
    password: str


@dataclass(frozen=True)
class DigestChallenge:
    """A server's ``WWW-Authenticate: Digest ...`` challenge (MD5, ``qop=auth`` only).

    Attributes:
        realm: the protection space (RWS 1.0: ``validusers@robapi.abb``).
        nonce: the server's nonce.
        opaque: a value the client returns unchanged.
        stale: the refused request had a correct digest with an expired nonce: retry with this nonce.
    """

    realm: str
    nonce: str
    opaque: str
    stale: bool = False

    def header_value(self) -> str:
        """The ``WWW-Authenticate`` value."""
        return (
            f'Digest realm="{self.realm}", qop="auth", nonce="{self.nonce}", opaque="{self.opaque}", '
            f'algorithm="MD5", stale={"TRUE" if self.stale else "FALSE"}'
        )


@dataclass(frozen=True)
class DigestAuthorization:
    """A client's parsed ``Authorization: Digest ...`` header.

    Attributes:
        username, realm, nonce, uri, opaque, cnonce: as sent.
        response: the 32 hex digit response digest.
        nc: the nonce count (sent as 8 hex digits).
    """

    username: str
    realm: str
    nonce: str
    uri: str
    response: str
    nc: int
    cnonce: str
    opaque: str


@dataclass(frozen=True)
class DigestVerdict:
    """The outcome of :func:`check_authorization`.

    Attributes:
        reason: None if accepted, else why it was refused.
        stale: refused only because the nonce expired (answer with a fresh challenge, ``stale=TRUE``).
        nonce: the request's nonce.
        nc: the request's nonce count (the caller stores it as the nonce's last count when accepted).
    """

    reason: Rejection | None
    stale: bool
    nonce: str
    nc: int


def _md5_hex(text: str) -> str:
    return hashlib.md5(text.encode(), usedforsecurity=False).hexdigest()


def digest_response(
    credentials: Credentials, realm: str, method: str, uri: str, nonce: str, nc: int, cnonce: str
) -> str:
    """The response digest for ``qop=auth`` (RFC 2617 §3.2.2.1), 32 lowercase hex digits."""
    ha1 = _md5_hex(f"{credentials.username}:{realm}:{credentials.password}")
    ha2 = _md5_hex(f"{method}:{uri}")
    return _md5_hex(f"{ha1}:{nonce}:{nc:08x}:{cnonce}:auth:{ha2}")


def parse_params(value: str, scheme: str = "Digest") -> dict[str, str]:
    """The ``name=value`` parameters of a Digest header value (values quoted or tokens; names lowercased).

    Raises:
        DigestError: too long, another scheme, a parameter that does not parse, or one given twice.
    """
    if len(value) > MAX_HEADER_CHARS:
        raise DigestError(f"header of {len(value)} characters; at most {MAX_HEADER_CHARS} allowed")
    head, _, rest = value.strip().partition(" ")
    if head.lower() != scheme.lower():
        raise DigestError(f"scheme {head[:20]!r}; allowed: {scheme}")
    params: dict[str, str] = {}
    pos = 0
    rest = rest.strip()
    while pos < len(rest):
        match = _PARAM.match(rest, pos)
        if match is None or match.end() == pos:
            raise DigestError(f"unparsable parameter at character {pos}: {rest[pos : pos + 20]!r}")
        name = match.group(1).lower()
        quoted, token = match.group(2), match.group(3)
        if name in params:
            raise DigestError(f"parameter {name!r} given twice")
        params[name] = re.sub(r"\\(.)", r"\1", quoted) if quoted is not None else token
        pos = match.end()
    return params


def _required(params: dict[str, str], name: str) -> str:
    try:
        return params[name]
    except KeyError:
        raise DigestError(f"parameter {name!r} missing; given: {', '.join(sorted(params)) or 'none'}") from None


def parse_challenge(value: str) -> DigestChallenge:
    """A server's ``WWW-Authenticate`` value.

    Raises:
        DigestError: not Digest, no realm or nonce, or an algorithm or qop other than MD5 / ``auth``.
    """
    params = parse_params(value)
    algorithm = params.get("algorithm", "MD5")
    if algorithm.upper() != "MD5":
        raise DigestError(f"algorithm {algorithm!r}; allowed: MD5")
    qops = [q.strip() for q in params.get("qop", "").split(",")]
    if "auth" not in qops:
        raise DigestError(f"qop {params.get('qop')!r}; allowed: auth")
    return DigestChallenge(
        realm=_required(params, "realm"),
        nonce=_required(params, "nonce"),
        opaque=params.get("opaque", ""),
        stale=params.get("stale", "").upper() == "TRUE",
    )


def authorization_header(
    challenge: DigestChallenge, credentials: Credentials, method: str, uri: str, nc: int, cnonce: str
) -> str:
    """The client's ``Authorization`` value answering ``challenge`` for one request.

    Args:
        challenge: the server's challenge (its nonce may be reused with a growing ``nc``).
        credentials: user name and password.
        method: the request's method (``GET``, ``POST``).
        uri: the request target exactly as sent (path and query).
        nc: the nonce count, 1 for the first request with this nonce, then one more for each request.
        cnonce: the client's nonce (printable, no quote).
    """
    response = digest_response(credentials, challenge.realm, method, uri, challenge.nonce, nc, cnonce)
    return (
        f'Digest username="{credentials.username}", realm="{challenge.realm}", nonce="{challenge.nonce}", '
        f'uri="{uri}", algorithm="MD5", response="{response}", opaque="{challenge.opaque}", qop="auth", '
        f'nc={nc:08x}, cnonce="{cnonce}"'
    )


def parse_authorization(value: str) -> DigestAuthorization:
    """A client's ``Authorization`` value.

    Raises:
        DigestError: not Digest, a field missing, ``qop`` other than ``auth``, an algorithm other than MD5, ``nc`` not
            8 hex digits, or a ``cnonce`` that is not 1-64 printable characters.
    """
    params = parse_params(value)
    qop = _required(params, "qop")
    if qop != "auth":
        raise DigestError(f"qop {qop[:20]!r}; allowed: auth")
    algorithm = params.get("algorithm", "MD5")
    if algorithm.upper() != "MD5":
        raise DigestError(f"algorithm {algorithm[:20]!r}; allowed: MD5")
    nc_text = _required(params, "nc")
    if _NC.fullmatch(nc_text) is None:
        raise DigestError(f"nc {nc_text[:20]!r}; allowed: 8 hex digits")
    cnonce = _required(params, "cnonce")
    if _CNONCE.fullmatch(cnonce) is None:
        raise DigestError("cnonce: allowed 1-64 printable characters")
    return DigestAuthorization(
        username=_required(params, "username"),
        realm=_required(params, "realm"),
        nonce=_required(params, "nonce"),
        uri=_required(params, "uri"),
        response=_required(params, "response"),
        nc=int(nc_text, 16),
        cnonce=cnonce,
        opaque=params.get("opaque", ""),
    )


def _nonce_mac(secret: bytes, issued_hex: str) -> str:
    return hmac.new(secret, issued_hex.encode(), hashlib.sha256).hexdigest()


def make_nonce(secret: bytes, issued_mono_ns: int) -> str:
    """A nonce the server can verify and date without remembering it.

    Args:
        secret: the server's random secret (at least 16 bytes, kept for the server's life).
        issued_mono_ns: now [ns, the server's monotonic clock].
    """
    issued_hex = f"{issued_mono_ns:x}"
    return f"{issued_hex}.{_nonce_mac(secret, issued_hex)}"


def nonce_issued_ns(secret: bytes, nonce: str) -> int | None:
    """When ``nonce`` was issued by a server holding ``secret`` [ns, its monotonic clock]; None if it was not."""
    issued_hex, dot, mac = nonce.partition(".")
    if not dot or not 0 < len(issued_hex) <= 16 or re.fullmatch(r"[0-9a-f]+", issued_hex) is None:
        return None
    if not hmac.compare_digest(mac.encode(), _nonce_mac(secret, issued_hex).encode()):
        return None
    return int(issued_hex, 16)


def check_authorization(
    auth: DigestAuthorization,
    method: str,
    uri: str,
    credentials: Credentials,
    realm: str,
    secret: bytes,
    opaque: str,
    now_mono_ns: int,
    last_nc: int | None,
) -> DigestVerdict:
    """Decide whether a parsed Authorization authenticates one request.

    Args:
        auth: the parsed header (:func:`parse_authorization`).
        method: the request's method.
        uri: the request target as received (path and query).
        credentials: the one user this server knows.
        realm: the server's realm.
        secret: the secret the server's nonces are made with (:func:`make_nonce`).
        opaque: the opaque value the server's challenges carry.
        now_mono_ns: now [ns, the server's monotonic clock].
        last_nc: the highest nonce count accepted so far with ``auth.nonce``; None if none (counts start at 1).

    Returns:
        The verdict; refused with the first failing check in the order user, realm, uri, nonce, opaque, response,
        age (``stale``), count (``replay``). The digest is checked before the age so that ``stale`` (an invitation
        to retry) is only given to a client that knows the password.
    """
    reason: Rejection | None = None
    user_ok = hmac.compare_digest(auth.username.encode(), credentials.username.encode())
    expected = digest_response(credentials, realm, method, uri, auth.nonce, auth.nc, auth.cnonce)
    response_ok = hmac.compare_digest(auth.response.lower().encode(), expected.encode())
    issued_ns = nonce_issued_ns(secret, auth.nonce)
    if not user_ok:
        reason = "bad_user"
    elif auth.realm != realm:
        reason = "bad_realm"
    elif auth.uri != uri:
        reason = "bad_uri"
    elif issued_ns is None:
        reason = "bad_nonce"
    elif not hmac.compare_digest(auth.opaque.encode(), opaque.encode()):
        reason = "bad_opaque"
    elif not response_ok:
        reason = "bad_response"
    elif (now_mono_ns - issued_ns) / 1e9 > NONCE_LIFETIME_S or issued_ns > now_mono_ns:
        reason = "stale"
    elif auth.nc <= (0 if last_nc is None else last_nc):
        reason = "replay"
    return DigestVerdict(reason=reason, stale=reason == "stale", nonce=auth.nonce, nc=auth.nc)
