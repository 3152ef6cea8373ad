#!/usr/bin/env bash
# Builds (once) a Debian sid root filesystem holding Debian's Blender 5.2 LTS, Xvfb and the
# screenshot tools, for the real-window tests (./dev.sh test-blender). Cached outside the
# repository; rebuilt when missing or incomplete. Needs root and debootstrap.
#   scripts/blender_root.sh [DIR]     (default: $IGS_BLENDER_ROOT or /var/cache/intrinsic-splats/blender-sid)
set -euo pipefail

ROOT=${1:-${IGS_BLENDER_ROOT:-/var/cache/intrinsic-splats/blender-sid}}
STAMP="$ROOT/.igs-root-complete"
# Bump when the package list below changes, so cached roots are rebuilt.
RECIPE=4

if [ -f "$STAMP" ] && [ "$(cat "$STAMP")" = "$RECIPE" ]; then
  echo "$ROOT"; exit 0
fi
[ "$(id -u)" = 0 ] || { echo "blender_root.sh: needs root (debootstrap, chroot)" >&2; exit 3; }
command -v debootstrap >/dev/null || { echo "blender_root.sh: debootstrap is not installed (apt-get install debootstrap)" >&2; exit 3; }

# Build next to the old root and swap it in only when complete.
NEW="$ROOT.new"
rm -rf "$NEW"
mkdir -p "$(dirname "$ROOT")"
echo "== debootstrap sid into $NEW (about 1 minute) ==" >&2
debootstrap --variant=minbase sid "$NEW" http://deb.debian.org/debian >"$NEW.log" 2>&1 \
  || { tail -20 "$NEW.log" >&2; echo "blender_root.sh: debootstrap failed (log: $NEW.log)" >&2; exit 1; }

cp /etc/resolv.conf "$NEW/etc/resolv.conf"
# The host's pip configuration and CA bundle (under its own name: the root's ca-certificates
# package rewrites the standard one), so pip reaches the same registries inside.
[ -f /etc/pip.conf ] && cp /etc/pip.conf "$NEW/etc/"
HOST_CA=${PIP_CERT:-/etc/ssl/certs/ca-certificates.crt}
[ -f "$HOST_CA" ] && cp "$HOST_CA" "$NEW/etc/igs-host-ca.pem"

in_root() { chroot "$NEW" /usr/bin/env -i PATH=/usr/sbin:/usr/bin:/sbin:/bin HOME=/root LANG=C.UTF-8 \
  DEBIAN_FRONTEND=noninteractive PIP_CERT=/etc/igs-host-ca.pem PIP_DISABLE_PIP_VERSION_CHECK=1 "$@"; }
mount -t proc proc "$NEW/proc"
trap 'umount "$NEW/proc" 2>/dev/null || true' EXIT

echo "== apt-get install blender xvfb ... (about 2 minutes) ==" >&2
# sid's Release file is often past its Valid-Until on mirrors and snapshots.
APT="apt-get -o Acquire::Check-Valid-Until=false -o Acquire::Retries=3"
in_root $APT update -qq >>"$NEW.log" 2>&1
in_root $APT install -y -qq --no-install-recommends \
  blender xvfb xauth xdotool imagemagick python3-numpy python3-requests python3-pip python3-venv ca-certificates \
  >>"$NEW.log" 2>&1 || { tail -20 "$NEW.log" >&2; echo "blender_root.sh: apt-get install failed (log: $NEW.log)" >&2; exit 1; }
# Debian's Blender imports cattrs, which Debian does not package.
in_root pip install -q --break-system-packages cattrs >>"$NEW.log" 2>&1 \
  || { tail -20 "$NEW.log" >&2; echo "blender_root.sh: pip install cattrs failed" >&2; exit 1; }
in_root blender --version >>"$NEW.log" 2>&1 || { tail -20 "$NEW.log" >&2; echo "blender_root.sh: blender does not start" >&2; exit 1; }
in_root $APT clean >/dev/null 2>&1 || true

umount "$NEW/proc"; trap - EXIT
echo "$RECIPE" > "$NEW/.igs-root-complete"
rm -rf "$ROOT.old"; [ -d "$ROOT" ] && mv "$ROOT" "$ROOT.old"
mv "$NEW" "$ROOT"; mv "$NEW.log" "$ROOT.log"; rm -rf "$ROOT.old"
echo "$ROOT"
