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
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq "${missing[@]}" >/dev/null
# The Debian package creates and starts a system cluster on 5432; citylod runs its own under var/pg.
