#!/bin/sh
# Install hostd as a systemd service (run as root from a checkout of the project):
#
#   sh systemd/install.sh              one printer:  hostd.service, /etc/hostd/hostd.toml
#   sh systemd/install.sh left right   one instance per printer id: hostd@left, hostd@right
#
# Environment: PREFIX (virtual environment, default /opt/hostd); DESTDIR (stage the
# files under this folder instead of /, and touch neither users nor systemd);
# HOSTD_SKIP_VENV=1 (keep an existing virtual environment as it is).
# Nothing is enabled or started: the last lines printed say how.
set -eu

PREFIX=${PREFIX:-/opt/hostd}
DESTDIR=${DESTDIR:-}
HERE=$(cd "$(dirname "$0")" && pwd)
SOURCE=$(dirname "$HERE")

say() { printf '%s\n' "$*"; }

if [ "${HOSTD_SKIP_VENV:-0}" != 1 ]; then
    say "virtual environment in $DESTDIR$PREFIX"
    python3 -m venv "$DESTDIR$PREFIX"
    "$DESTDIR$PREFIX/bin/pip" install --quiet --upgrade pip
    "$DESTDIR$PREFIX/bin/pip" install --quiet "$SOURCE"
fi
install -d "$DESTDIR/usr/local/bin"
ln -sf "$PREFIX/bin/hostd" "$DESTDIR/usr/local/bin/hostd"

install -d "$DESTDIR/usr/lib/sysusers.d" "$DESTDIR/usr/lib/tmpfiles.d" \
    "$DESTDIR/etc/systemd/system" "$DESTDIR/etc/hostd"
install -m 0644 "$HERE/hostd.sysusers.conf" "$DESTDIR/usr/lib/sysusers.d/hostd.conf"
install -m 0644 "$HERE/hostd.tmpfiles.conf" "$DESTDIR/usr/lib/tmpfiles.d/hostd.conf"
install -m 0644 "$HERE/hostd.service" "$HERE/hostd@.service" "$DESTDIR/etc/systemd/system/"

# config files are never overwritten: they are the administrator's
configs=""
if [ "$#" -eq 0 ]; then
    target="$DESTDIR/etc/hostd/hostd.toml"
    [ -e "$target" ] || install -m 0640 "$HERE/hostd.toml.example" "$target"
    configs="$target"
    units=" hostd.service"
else
    units=""
    for id in "$@"; do
        case "$id" in
            *[!A-Za-z0-9_.-]*|"") say "printer id '$id': letters, digits, '.', '_', '-' only" >&2
                                  exit 2 ;;
        esac
        target="$DESTDIR/etc/hostd/$id.toml"
        if [ ! -e "$target" ]; then
            sed -e "/^#/!s|/var/lib/hostd|/var/lib/hostd/$id|g" \
                -e "s|^id = \"printer1\"|id = \"$id\"|" \
                "$HERE/hostd.toml.example" > "$target"
            chmod 0640 "$target"
        fi
        configs="$configs $target"
        units="$units hostd@$id.service"
    done
fi

if [ -z "$DESTDIR" ]; then
    systemd-sysusers
    systemd-tmpfiles --create /usr/lib/tmpfiles.d/hostd.conf
    for config in $configs; do chgrp hostd "$config"; done
    systemctl daemon-reload
fi

say "installed. Next:"
for config in $configs; do say "  edit ${config#"$DESTDIR"}   (serial port, bed size, MQTT)"; done
say "  systemctl enable --now$units"
for config in $configs; do
    say "  sudo -u hostd hostd status --config ${config#"$DESTDIR"}"
done
say "  journalctl -u 'hostd*' -f"
