#!/usr/bin/env bash
# A lab / test PKI for a secure servowatch station: one CA and one certificate per identity.
#
#   deploy/pki/make-certs.sh OUTDIR [COMMON_NAME ...]
#
# Without names it makes the identities of the shipped configs (deploy/secure/):
#   router  monitor.ground1.0  monitor.ground1.1  monitor.ground2.0  operator  dashboard
#   acq-AC001  acq-AC002  sim-AC001  sim-AC002
# The role is the common name's prefix (see docs/security.md): router, monitor.<STATION>.<SHARD>
# (one per daemon), operator, dashboard, acq-<AIRCRAFT> (acquisition), sim-<AIRCRAFT> (virtual
# actuators).
# OUTDIR gets ca.pem (the CA certificate to distribute), ca.key (keep it off the station),
# and <name>.pem / <name>.key per identity (keys mode 0600). An existing CA in OUTDIR is
# reused, so the script can add identities later. The router certificate names localhost and
# 127.0.0.1; add the station's own names with ROUTER_SANS="DNS:station1.example,IP:10.0.0.5".
# Keys are ECDSA P-256 in PKCS#8 PEM; certificates are valid DAYS days (default 365).
# A real installation uses its organisation's PKI instead: see docs/security.md.
set -euo pipefail
umask 077
if [[ $# -lt 1 ]]; then
  echo "usage: $0 OUTDIR [COMMON_NAME ...]" >&2
  exit 2
fi
out="$1"
shift
names=("$@")
if [[ ${#names[@]} -eq 0 ]]; then
  names=(router monitor.ground1.0 monitor.ground1.1 monitor.ground2.0 operator dashboard
    acq-AC001 acq-AC002 sim-AC001 sim-AC002)
fi
days="${DAYS:-365}"
sans="DNS:localhost,IP:127.0.0.1${ROUTER_SANS:+,$ROUTER_SANS}"
command -v openssl > /dev/null || { echo "$0: openssl not found" >&2; exit 1; }
mkdir -p "$out"
cd "$out"

if [[ ! -f ca.pem || ! -f ca.key ]]; then
  openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out ca.key 2> /dev/null
  openssl req -x509 -new -key ca.key -sha256 -days "$days" -subj "/CN=servowatch lab CA" \
    -addext "basicConstraints=critical,CA:TRUE" \
    -addext "keyUsage=critical,keyCertSign,cRLSign" -out ca.pem 2> /dev/null
fi

for name in "${names[@]}"; do
  if [[ ! "$name" =~ ^[A-Za-z0-9_.-]+$ ]]; then
    echo "$0: bad common name '$name' (letters, digits, _ . - only)" >&2
    exit 2
  fi
  if [[ "$name" == router* ]]; then
    ext="basicConstraints=critical,CA:FALSE
keyUsage=critical,digitalSignature
extendedKeyUsage=serverAuth,clientAuth
subjectAltName=$sans"
  else
    ext="basicConstraints=critical,CA:FALSE
keyUsage=critical,digitalSignature
extendedKeyUsage=clientAuth"
  fi
  openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$name.key" 2> /dev/null
  openssl req -new -key "$name.key" -subj "/CN=$name" -out "$name.csr" 2> /dev/null
  openssl x509 -req -in "$name.csr" -CA ca.pem -CAkey ca.key -CAcreateserial -sha256 \
    -days "$days" -extfile <(printf '%s\n' "$ext") -out "$name.pem" 2> /dev/null
  rm -f "$name.csr"
  chmod 0644 "$name.pem"
done
chmod 0644 ca.pem
rm -f ca.srl
echo "CA and ${#names[@]} certificate(s) in $out: ${names[*]}"
