#!/bin/sh
# The host cases of docs/tls.md ("Choosing the engine"), for both engines:
# openssl s_client against rustls-host and mbedtls-host on 127.0.0.1.
#   sh host-cases.sh            (from spikes/tls; builds both host programs)
# The last cases run rustls with the spike's own provider.
# Each case prints the server's lines (outcome, role, arena peak) and the
# client's protocol/cipher/error lines.
set -u
cd "$(dirname "$0")"
: "${CARGO_TARGET_DIR:=$PWD/target}"
export CARGO_TARGET_DIR
cargo build -q --release --bin rustls-host --bin mbedtls-host || exit 2
C=certs
port=4500
case_() { # engine limit s_client-args...
  b=$1; limit=$2; shift 2
  port=$((port + 1))
  "$CARGO_TARGET_DIR/release/$b-host" $port $limit 1 > /tmp/tls-spike-srv.log 2>&1 &
  sleep 0.5
  sleep 1 | timeout 10 openssl s_client -connect 127.0.0.1:$port -CAfile $C/server.pem "$@" > /tmp/tls-spike-cli.log 2>&1
  sleep 0.5
  echo "== $b, arena limit $limit (0: all), $*"
  grep -v '^ \|^stack\|^note\|^listening' /tmp/tls-spike-srv.log
  grep -E 'Cipher is|hello|alert|:error:' /tmp/tls-spike-cli.log | head -3
}
for b in rustls mbedtls; do
  for v in -tls1_3 -tls1_2; do
    for who in operator viewer norole stranger mid big; do
      case_ $b 0 $v -cert $C/$who.pem -key $C/$who.key
    done
    case_ $b 0 $v
  done
done
case_ rustls 4000 -tls1_3 -cert $C/operator.pem -key $C/operator.key
case_ rustls 9000 -tls1_3 -cert $C/operator.pem -key $C/operator.key
case_ mbedtls 20000 -tls1_3 -cert $C/operator.pem -key $C/operator.key
case_ mbedtls 30000 -tls1_3 -cert $C/operator.pem -key $C/operator.key
case_ mbedtls 30000 -tls1_2 -cert $C/operator.pem -key $C/operator.key
# rustls with the spike's own minimal provider (rustls-spike/src/own.rs).
cargo build -q --release --bin rustls-host --features own-provider || exit 2
for v in -tls1_3 -tls1_2; do
  for who in operator stranger mid; do
    case_ rustls 0 $v -cert $C/$who.pem -key $C/$who.key
  done
done
case_ rustls 4000 -tls1_3 -cert $C/operator.pem -key $C/operator.key
