#!/usr/bin/env bash
# Make a private CA and certificates for a bipedtele deployment over the internet.
#
#   make-certs.sh OUT_DIR ROUTER_NAME [ROUTER_NAME ...]
#
# Run it from any folder (by its path, e.g. /path/to/bipedtele/scripts/make-certs.sh);
# OUT_DIR is relative to the working folder. `bipedtele setup certs OUT_DIR NAME...` does
# the same from an installed package, and `bipedtele setup two-hosts` also writes the
# passwords, the message key and one folder per host (docs/two-continents.md).
#
# ROUTER_NAME: the DNS names and/or IP addresses (IPv4 or IPv6) by which the leader and
# follower reach the router; they go into its certificate's subjectAltName, and the
# clients must connect by one of them (tls/NAME:7447). Writes:
#   OUT_DIR/ca.pem                        the CA certificate: copy to every host
#   OUT_DIR/router.pem  router.key        the router's server certificate
#   OUT_DIR/leader.pem  leader.key        client certificates for mutual TLS
#   OUT_DIR/follower.pem  follower.key
#   OUT_DIR/ca-private/ca.key             the CA's key: keep it OFF the hosts (offline);
#                                         it only signs new certificates
# Each host gets ca.pem and its own pem/key pair; copying OUT_DIR's files (not the
# ca-private folder) never copies the CA's key. Keys are mode 0600. Nothing is overwritten.
set -euo pipefail
usage="usage: make-certs.sh OUT_DIR ROUTER_NAME [ROUTER_NAME ...]  (DNS names or IP addresses of the router)"
if [[ $# -lt 2 ]]; then
    echo "$usage" >&2
    exit 2
fi
out=$1; shift
command -v openssl >/dev/null || { echo "make-certs: openssl is required (apt-get install openssl)" >&2; exit 2; }

san=""
for name in "$@"; do
    if [[ $name =~ ^[0-9]+\.[0-9]+\.[0-9]+\.[0-9]+$ || $name == *:* ]]; then
        san+="IP:$name,"
    elif [[ $name =~ ^[A-Za-z0-9]([A-Za-z0-9.-]*[A-Za-z0-9])?$ && ! $name =~ ^[0-9.]+$ ]]; then
        san+="DNS:$name,"
    else
        echo "make-certs: $name: allowed: a DNS name (router.example.org) or an IP address" >&2
        exit 2
    fi
done
san=${san%,}

private="$out/ca-private"
for f in "$out/ca.pem" "$private/ca.key"; do
    if [[ -e $f ]]; then
        echo "make-certs: $f exists; allowed: a folder without certificates (nothing is overwritten)" >&2
        exit 2
    fi
done
mkdir -p "$out"
umask 077
mkdir -p "$private"
chmod 700 "$private"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

days=825
openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes -days 3650 \
    -keyout "$private/ca.key" -out "$out/ca.pem" -subj "/CN=bipedtele CA" \
    -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign" 2>/dev/null

issue() {  # issue NAME SAN EXTENDED_KEY_USAGE
    local name=$1 alt=$2 eku=$3
    openssl req -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes \
        -keyout "$out/$name.key" -out "$tmp/$name.csr" -subj "/CN=$name" 2>/dev/null
    printf 'basicConstraints=CA:FALSE\nkeyUsage=critical,digitalSignature,keyEncipherment\nextendedKeyUsage=%s\nsubjectAltName=%s\n' \
        "$eku" "$alt" > "$tmp/$name.ext"
    openssl x509 -req -in "$tmp/$name.csr" -CA "$out/ca.pem" -CAkey "$private/ca.key" \
        -set_serial "0x$(openssl rand -hex 16)" \
        -days "$days" -out "$out/$name.pem" -extfile "$tmp/$name.ext" 2>/dev/null
}
issue router "$san" serverAuth,clientAuth
issue leader "DNS:leader" clientAuth,serverAuth
issue follower "DNS:follower" clientAuth,serverAuth
chmod 644 "$out"/*.pem
chmod 600 "$out"/*.key "$private/ca.key"
echo "make-certs: wrote CA, router, leader and follower certificates to $out ($san)"
echo "make-certs: $private/ca.key is the CA's key: keep it off the hosts"
