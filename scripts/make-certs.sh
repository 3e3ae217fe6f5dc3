#!/usr/bin/env bash
# Make a private CA and certificates for a bipedtele deployment over the internet.
#
#   scripts/make-certs.sh OUT_DIR ROUTER_NAME [ROUTER_NAME ...]
#
# ROUTER_NAME: the DNS names and/or IP addresses the leader and follower use to reach the
# router (they go into its certificate's subjectAltName). Writes:
#   OUT_DIR/ca.pem  ca.key                 the CA (keep ca.key offline)
#   OUT_DIR/router.pem  router.key         the router's server certificate
#   OUT_DIR/leader.pem  leader.key         client certificates for mutual TLS
#   OUT_DIR/follower.pem  follower.key
# Copy ca.pem to every machine; each process gets its own pem/key pair.
set -euo pipefail
if [[ $# -lt 2 ]]; then
    echo "usage: $0 OUT_DIR ROUTER_NAME [ROUTER_NAME ...]  (names or IPs of the router)" >&2
    exit 2
fi
out=$1; shift
command -v openssl >/dev/null || { echo "make-certs: openssl is required (apt-get install openssl)" >&2; exit 2; }
mkdir -p "$out"
umask 077

san=""
for name in "$@"; do
    if [[ $name =~ ^[0-9.]+$ || $name == *:* ]]; then san+="IP:$name,"; else san+="DNS:$name,"; fi
done
san=${san%,}

days=825
openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes -days 3650 \
    -keyout "$out/ca.key" -out "$out/ca.pem" -subj "/CN=bipedtele CA" \
    -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign" 2>/dev/null

issue() {  # issue NAME SAN EXTENDED_KEY_USAGE
    local name=$1 alt=$2 eku=$3
    openssl req -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes \
        -keyout "$out/$name.key" -out "$out/$name.csr" -subj "/CN=$name" 2>/dev/null
    printf 'basicConstraints=CA:FALSE\nkeyUsage=critical,digitalSignature,keyEncipherment\nextendedKeyUsage=%s\nsubjectAltName=%s\n' \
        "$eku" "$alt" > "$out/$name.ext"
    openssl x509 -req -in "$out/$name.csr" -CA "$out/ca.pem" -CAkey "$out/ca.key" -CAcreateserial \
        -days "$days" -out "$out/$name.pem" -extfile "$out/$name.ext" 2>/dev/null
    rm -f "$out/$name.csr" "$out/$name.ext"
}
issue router "$san" serverAuth,clientAuth
issue leader "DNS:leader" clientAuth,serverAuth
issue follower "DNS:follower" clientAuth,serverAuth
rm -f "$out/ca.srl"
chmod 644 "$out"/*.pem
echo "make-certs: wrote CA, router, leader and follower certificates to $out"
