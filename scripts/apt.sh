# Sourced by scripts/setup.sh and scripts/test.sh: Debian packages, installed when missing.
#   apt_need PKG...           # installs those of PKG... that dpkg does not list as installed
#   apt_install [OPTION] PKG...  # apt-get install (options such as --no-install-recommends)
# As root, or through sudo otherwise; apt-get update runs once per shell, before the first install.

_apt() {
  if [ "$(id -u)" = 0 ]; then
    DEBIAN_FRONTEND=noninteractive apt-get "$@"
  else
    sudo DEBIAN_FRONTEND=noninteractive apt-get "$@"
  fi
}

_APT_UPDATED=""

apt_install() {
  if [ -z "$_APT_UPDATED" ]; then
    _apt update -qq
    _APT_UPDATED=1
  fi
  _apt install -y -qq "$@" >/dev/null
}

apt_need() {
  local need=() p
  for p in "$@"; do
    dpkg -s "$p" >/dev/null 2>&1 || need+=("$p")
  done
  if [ ${#need[@]} -gt 0 ]; then
    echo "installing Debian packages: ${need[*]}" >&2
    apt_install "${need[@]}"
  fi
}
