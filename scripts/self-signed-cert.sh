#!/bin/sh
# A self-signed TLS certificate for `facesim-editor serve --tls-cert DIR/cert.pem --tls-key
# DIR/key.pem`, naming this machine's loopback (and any names given after DIR, e.g.
# DNS:studio.example or IP:10.0.0.5). Clients trust it with `--tls-ca DIR/cert.pem`; a
# browser asks once. For a server others reach, prefer a certificate from your CA.
# Usage: scripts/self-signed-cert.sh DIR [NAME ...]    (needs openssl)
set -eu
dir=$1
shift
names="DNS:localhost,IP:127.0.0.1"
for n in "$@"; do names="$names,$n"; done
mkdir -p "$dir"
openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes -days 365 \
  -subj /CN=facesim -addext "subjectAltName=$names" \
  -addext "basicConstraints=critical,CA:FALSE" \
  -keyout "$dir/key.pem" -out "$dir/cert.pem" 2>/dev/null
chmod 600 "$dir/key.pem"
echo "$dir/cert.pem $dir/key.pem"
