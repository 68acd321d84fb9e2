#!/usr/bin/env bash
# Installs the Debian packages listed in scripts/packages.txt that are missing.
# Needs root (apt-get); prints what is missing and how to install it otherwise.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
mapfile -t pkgs < <(grep -v '^#' "$here/packages.txt" | sed '/^\s*$/d')
if [ "${EXTRA_PACKAGES:-}" != "" ]; then pkgs+=(${EXTRA_PACKAGES}); fi
missing=()
for p in "${pkgs[@]}"; do
  st=$(dpkg-query -W -f='${Status}' "$p" 2>/dev/null || true)
  [ "$st" = "install ok installed" ] || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  echo "[deps] all ${#pkgs[@]} Debian packages present"
  exit 0
fi
echo "[deps] missing: ${missing[*]}"
if [ "$(id -u)" != "0" ]; then
  echo "[deps] ERROR: not root; install them with: sudo apt-get update && sudo apt-get install -y --no-install-recommends ${missing[*]}" >&2
  exit 1
fi
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq
apt-get install -y -qq --no-install-recommends "${missing[@]}"
echo "[deps] installed ${#missing[@]} packages"
