#!/usr/bin/env bash
# Creates .venv with the project and its development tools, once per change of pyproject.toml.
# Needs only Python >= 3.11 and the package registry.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
  echo "bootstrap: creating .venv with $($PYTHON --version)" >&2
  "$PYTHON" -m venv .venv
fi
stamp=".venv/.installed-$(sha256sum pyproject.toml | cut -c1-16)"
if [ ! -f "$stamp" ]; then
  echo "bootstrap: installing the project and its dependencies into .venv" >&2
  .venv/bin/python -m pip install --quiet --upgrade pip
  .venv/bin/python -m pip install --quiet -e ".[dev]"
  rm -f .venv/.installed-*
  touch "$stamp"
fi
# The operator page's browser test (tests/test_operator_browser.py) drives Debian's chromium with its chromedriver.
# Installed only when missing, as root, with apt; elsewhere that test skips and says why.
if ! command -v chromium >/dev/null 2>&1 || ! command -v chromedriver >/dev/null 2>&1; then
  if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
    echo "bootstrap: installing chromium and chromium-driver (for the operator page's browser test)" >&2
    if ! { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver; } \
        >/tmp/hrc-bootstrap-apt.log 2>&1; then
      echo "bootstrap: could not install chromium (see /tmp/hrc-bootstrap-apt.log); the browser test will skip" >&2
    fi
  else
    echo "bootstrap: chromium/chromedriver missing and not root with apt: the browser test will skip" >&2
  fi
fi
# promtool (tests/test_http_operator.py checks /metrics with it) from Debian's prometheus package: only the tool is
# unpacked into .venv/bin, the server is not installed (no service). Elsewhere that test skips and says why.
if ! command -v promtool >/dev/null 2>&1 && [ ! -x .venv/bin/promtool ] && command -v apt-get >/dev/null 2>&1; then
  echo "bootstrap: unpacking promtool from Debian's prometheus package into .venv/bin" >&2
  promdir="$(mktemp -d)"
  if ! { { [ "$(id -u)" != "0" ] || apt-get update -qq; } && (cd "$promdir" && apt-get download prometheus) \
      && dpkg-deb -x "$promdir"/prometheus_*.deb "$promdir/x" && cp "$promdir/x/usr/bin/promtool" .venv/bin/promtool; } \
      >/tmp/hrc-bootstrap-promtool.log 2>&1; then
    echo "bootstrap: could not unpack promtool (see /tmp/hrc-bootstrap-promtool.log); the promtool test will skip" >&2
  fi
  rm -rf "$promdir"
fi
# libfaketime (Debian's package libfaketime): the soak (bench/soak.py) and tests/e2e/test_clock_step.py step an
# emulator's wall clock through it. Installed only when missing, as root, with apt; elsewhere the soak reports the
# clock steps as not injected and the test skips, each saying why.
# (Any one of the places will do: `ls` of all three fails when one is absent, and reinstalled it on every run.)
have_faketime() {
  local f
  for f in /usr/lib/*/faketime/libfaketimeMT.so.1 /usr/lib/faketime/libfaketimeMT.so.1 \
      /usr/local/lib/faketime/libfaketimeMT.so.1; do
    [ -e "$f" ] && return 0
  done
  return 1
}
if ! have_faketime; then
  if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
    echo "bootstrap: installing libfaketime (for the soak's and the e2e test's wall-clock steps)" >&2
    if ! { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libfaketime; } \
        >/tmp/hrc-bootstrap-faketime.log 2>&1; then
      echo "bootstrap: could not install libfaketime (see /tmp/hrc-bootstrap-faketime.log); clock steps not injected" >&2
    fi
  else
    echo "bootstrap: libfaketime missing and not root with apt: the soak's clock steps are not injected" >&2
  fi
fi
