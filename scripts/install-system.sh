#!/usr/bin/env bash
# Installs the Debian packages citylod needs, only those missing. Idempotent; `make setup` calls it.
#   base:  PostgreSQL 15 + PostGIS 3 (with SFCGAL), python3-venv
#   test:  + Chromium (CesiumJS end-to-end test) and fonts
#   bench: + osm2pgsql (the reference loader `make bench` compares against)
set -euo pipefail
profile="${1:-base}"
pkgs=(postgresql-15 postgresql-15-postgis-3 postgresql-15-postgis-3-scripts)
# Debian's python3 imports ensurepip fine but cannot create a venv without python3-venv: try for real.
probe=$(mktemp -d)
python3 -m venv "$probe/v" >/dev/null 2>&1 || pkgs+=(python3-venv)
rm -rf "$probe"
case "$profile" in
  base) ;;
  test) pkgs+=(chromium fonts-liberation) ;;
  bench) pkgs+=(chromium fonts-liberation osm2pgsql) ;;
  *) echo "usage: $0 [base|test|bench]" >&2; exit 2 ;;
esac
missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'install ok installed' || missing+=("$p")
done
[ ${#missing[@]} -eq 0 ] && exit 0
echo "installing Debian packages: ${missing[*]}" >&2
SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  command -v sudo >/dev/null || { echo "need root (or sudo) to apt-get install ${missing[*]}" >&2; exit 1; }
  SUDO="sudo"
fi
export DEBIAN_FRONTEND=noninteractive
# A freshly booted machine often runs apt-daily or unattended-upgrades: wait for their locks instead of failing.
# DPkg::Lock::Timeout covers dpkg's locks (install); apt-get update's /var/lib/apt/lists/lock it does not
# (apt 2.6), so a run that could not get a lock is retried until the same deadline.
LOCK_WAIT_S="${CITYLOD_APT_LOCK_WAIT_S:-900}"
apt_get() {
  local deadline=$((SECONDS + LOCK_WAIT_S)) err
  err=$(mktemp)
  until $SUDO apt-get -o DPkg::Lock::Timeout="$LOCK_WAIT_S" "$@" 2>"$err"; do
    if grep -q 'Could not get lock' "$err" && [ "$SECONDS" -lt "$deadline" ]; then
      echo "apt-get $1: another apt holds its lock ($(grep -m1 -o 'held by process.*' "$err" || echo '?')); waiting" >&2
      sleep 10
    else
      cat "$err" >&2; rm -f "$err"; return 1
    fi
  done
  cat "$err" >&2; rm -f "$err"
}
apt_get update -qq
apt_get install -y -qq "${missing[@]}" >/dev/null
# The Debian package also creates and starts a system cluster on 5432, left alone: citylod runs its own under var/pg.
