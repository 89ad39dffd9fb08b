"""HTTP Digest (MD5, qop=auth): RFC 2617's known answer, requests' client accepted by our server check, our client
header checked by it, then every refusal (wrong password, forged or expired nonce, replayed count, wrong uri) and
malformed headers."""

from __future__ import annotations

import pytest
import requests

from hrc_devices.controllers.abb_rws.http_digest import (
    MAX_HEADER_CHARS,
    NONCE_LIFETIME_S,
    Credentials,
    DigestChallenge,
    DigestError,
    DigestVerdict,
    authorization_header,
    check_authorization,
    digest_response,
    make_nonce,
    nonce_issued_ns,
    parse_authorization,
    parse_challenge,
    parse_params,
)

SECRET = b"0123456789abcdef0123456789abcdef"
USER = Credentials("Default User", "robotics")
REALM = "validusers@robapi.abb"
OPAQUE = "799d5"
NOW_NS = 5_000_000_000
URI = "/rw/panel/speedratio?json=1"


def _challenge(now_ns: int = NOW_NS) -> DigestChallenge:
    return DigestChallenge(REALM, make_nonce(SECRET, now_ns), OPAQUE)


def _check(
    header: str, last_nc: int | None = None, now_ns: int = NOW_NS, method: str = "GET", uri: str = URI
) -> DigestVerdict:
    return check_authorization(parse_authorization(header), method, uri, USER, REALM, SECRET, OPAQUE, now_ns, last_nc)


def test_rfc2617_known_answer() -> None:
    # RFC 2617 §3.5: Mufasa / "Circle Of Life", GET /dir/index.html.
    response = digest_response(
        Credentials("Mufasa", "Circle Of Life"),
        "testrealm@host.com",
        "GET",
        "/dir/index.html",
        "dcd98b7102dd2f0e8b11d0f600bfb0c093",
        1,
        "0a4f113b",
    )
    assert response == "6629fae49393a05397450978507c4ef1"


def test_requests_client_header_is_accepted_and_its_next_count_too() -> None:
    challenge = _challenge()
    auth = requests.auth.HTTPDigestAuth(USER.username, USER.password)
    auth.init_per_thread_state()
    auth._thread_local.chal = requests.utils.parse_dict_header(challenge.header_value().removeprefix("Digest "))
    first = auth.build_digest_header("GET", f"http://127.0.0.1{URI}")
    second = auth.build_digest_header("GET", f"http://127.0.0.1{URI}")
    assert first is not None
    assert second is not None
    verdict = _check(first)
    assert verdict.reason is None
    assert verdict.nc == 1
    assert _check(second, last_nc=verdict.nc).reason is None


def test_our_client_header_is_accepted_and_parsed_back() -> None:
    challenge = parse_challenge(_challenge().header_value())
    header = authorization_header(challenge, USER, "POST", URI, 7, "c0ffee")
    auth = parse_authorization(header)
    assert (auth.username, auth.realm, auth.uri, auth.nc, auth.cnonce, auth.opaque) == (
        USER.username,
        REALM,
        URI,
        7,
        "c0ffee",
        OPAQUE,
    )
    assert _check(header, last_nc=6, method="POST").reason is None


def test_challenge_round_trip_keeps_stale() -> None:
    challenge = DigestChallenge(REALM, make_nonce(SECRET, NOW_NS), OPAQUE, stale=True)
    assert parse_challenge(challenge.header_value()) == challenge


@pytest.mark.parametrize(
    ("credentials", "method", "uri", "reason"),
    [
        (Credentials("Default User", "wrong"), "GET", URI, "bad_response"),
        (Credentials("Admin", "robotics"), "GET", URI, "bad_user"),
        (USER, "POST", URI, "bad_response"),  # signed for POST, sent as GET
        (USER, "GET", "/rw/panel/ctrlstate?json=1", "bad_uri"),  # signed for another uri
    ],
)
def test_wrong_credentials_method_or_uri_are_refused(
    credentials: Credentials, method: str, uri: str, reason: str
) -> None:
    header = authorization_header(_challenge(), credentials, method, uri, 1, "abc")
    assert _check(header).reason == reason


def test_replayed_or_repeated_count_is_refused() -> None:
    header = authorization_header(_challenge(), USER, "GET", URI, 3, "abc")
    assert _check(header, last_nc=2).reason is None
    assert _check(header, last_nc=3).reason == "replay"
    zero = authorization_header(_challenge(), USER, "GET", URI, 0, "abc")
    assert _check(zero).reason == "replay"


def test_forged_nonce_and_wrong_opaque_are_refused() -> None:
    forged = DigestChallenge(REALM, make_nonce(b"another secret of 32 bytes......", NOW_NS), OPAQUE)
    assert _check(authorization_header(forged, USER, "GET", URI, 1, "abc")).reason == "bad_nonce"
    assert nonce_issued_ns(SECRET, forged.nonce) is None
    assert nonce_issued_ns(SECRET, "zz.00") is None
    other_opaque = DigestChallenge(REALM, make_nonce(SECRET, NOW_NS), "other")
    assert _check(authorization_header(other_opaque, USER, "GET", URI, 1, "abc")).reason == "bad_opaque"


def test_expired_nonce_is_stale_only_for_a_correct_digest() -> None:
    old = _challenge(now_ns=NOW_NS)
    later_ns = NOW_NS + int((NONCE_LIFETIME_S + 1.0) * 1e9)
    good = authorization_header(old, USER, "GET", URI, 1, "abc")
    verdict = _check(good, now_ns=later_ns)
    assert verdict.reason == "stale"
    assert verdict.stale
    wrong = authorization_header(old, Credentials(USER.username, "wrong"), "GET", URI, 1, "abc")
    assert _check(wrong, now_ns=later_ns).reason == "bad_response"
    assert _check(good, now_ns=NOW_NS - 1).reason == "stale"  # issued "in the future": another process's nonce


@pytest.mark.parametrize(
    "header",
    [
        "Basic RGVmYXVsdCBVc2VyOnJvYm90aWNz",
        "Digest garbage",
        'Digest username="a", username="b"',
        'Digest username="a", realm="r", nonce="n", uri="/", response="x", qop=auth, nc=1, cnonce="c"',
        'Digest username="a", realm="r", nonce="n", uri="/", response="x", qop=auth-int, nc=00000001, cnonce="c"',
        'Digest username="a", realm="r", nonce="n", uri="/", response="x", qop=auth, nc=00000001, cnonce="c",'
        " algorithm=SHA-256",
        'Digest realm="r", nonce="n", uri="/", response="x", qop=auth, nc=00000001, cnonce="c"',
        'Digest username="a", realm="r", nonce="n", uri="/", response="x", qop=auth, nc=00000001, cnonce="c d"',
        "Digest " + "a" * MAX_HEADER_CHARS,
        "",
    ],
)
def test_malformed_authorization_raises(header: str) -> None:
    with pytest.raises(DigestError):
        parse_authorization(header)


def test_params_unquote_escapes_and_accept_tokens() -> None:
    params = parse_params(r'Digest realm="a \"b\", c", qop=auth, nc=00000001')
    assert params == {"realm": 'a "b", c', "qop": "auth", "nc": "00000001"}


@pytest.mark.parametrize(
    "header",
    [
        'Digest realm="r", nonce="n", qop="auth-int"',
        'Digest realm="r", nonce="n", qop="auth", algorithm=SHA',
        "Basic x",
    ],
)
def test_unusable_challenge_raises(header: str) -> None:
    with pytest.raises(DigestError):
        parse_challenge(header)
