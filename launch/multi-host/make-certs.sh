#!/usr/bin/env bash
# Creates a private CA and one TLS identity per host for a multi-host fiberflow run
# (launch/multi-host/multi-host.toml). Usage:
#   launch/multi-host/make-certs.sh OUT_DIR HOST_NAME[=DNS_NAME or IPv4 address] ...
# e.g. launch/multi-host/make-certs.sh launch/certs head=head.lab.example worker=worker.lab.example
# Writes OUT_DIR/ca.pem (give it to every host), OUT_DIR/<host>.pem and
# OUT_DIR/<host>-key.pem (give each host only its own). The certificate common name is
# fiberflow-<host>: list those names in network.allowed_common_names. Keys are EC P-256,
# valid 30 days; ca-key.pem stays on the machine that ran this script.
set -euo pipefail
out=${1:?usage: make-certs.sh OUT_DIR HOST[=DNS] ...}
shift
[ $# -ge 1 ] || { echo "name at least one host" >&2; exit 2; }
mkdir -p "$out"
umask 077
openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes \
  -keyout "$out/ca-key.pem" -out "$out/ca.pem" -days 30 -subj "/CN=fiberflow-run-ca" \
  -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign" 2>/dev/null
for spec in "$@"; do
  host=${spec%%=*}
  dns=${spec#*=}
  [ "$dns" = "$spec" ] && dns=localhost
  openssl req -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes \
    -keyout "$out/$host-key.pem" -out "$out/$host.csr" -subj "/CN=fiberflow-$host" 2>/dev/null
  # a host named by its address (e.g. head=10.0.0.1) gets it as an IP name
  if [[ $dns =~ ^[0-9]+\.[0-9]+\.[0-9]+\.[0-9]+$ ]]; then san="IP:$dns"; else san="DNS:$dns"; fi
  printf 'subjectAltName=%s,DNS:localhost,IP:127.0.0.1\nextendedKeyUsage=serverAuth,clientAuth\n' "$san" > "$out/$host.ext"
  openssl x509 -req -in "$out/$host.csr" -CA "$out/ca.pem" -CAkey "$out/ca-key.pem" \
    -CAcreateserial -out "$out/$host.pem" -days 30 -extfile "$out/$host.ext" 2>/dev/null
  rm -f "$out/$host.csr" "$out/$host.ext"
  echo "$out/$host.pem  (CN fiberflow-$host, $san)"
done
