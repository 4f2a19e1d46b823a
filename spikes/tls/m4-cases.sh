#!/bin/sh
# The M4 figures of docs/tls.md ("Choosing the engine"), for both engines:
# the handshake images in QEMU mps2-an386 with the instruction-counting
# plugin (qemu/marks.c), and the sizes of the full, server-only and
# baseline images.
#   sh m4-cases.sh              (from spikes/tls; needs gcc, qemu-system-arm,
#                                llvm-nm/llvm-size, clang/libclang/cmake/ninja)
set -eu
cd "$(dirname "$0")"
: "${CARGO_TARGET_DIR:=$PWD/target}"
export CARGO_TARGET_DIR
T=thumbv7em-none-eabihf
OUT=$CARGO_TARGET_DIR/tls-spike
mkdir -p "$OUT"
gcc -O2 -Wall -Wextra -shared -fPIC -o "$OUT/marks.so" qemu/marks.c
for b in rustls mbedtls; do
  for f in full server-only baseline; do
    if [ $f = full ]; then feat=""; else feat="--features $f"; fi
    # Mbed TLS's client code only in the full image (its in-image peer).
    if [ $b = mbedtls ] && [ $f != full ]; then feat="--no-default-features $feat"; fi
    RUSTFLAGS="-C link-arg=-Tlink.x" cargo build -q --release --bin $b-m4 --target $T $feat
    cp "$CARGO_TARGET_DIR/$T/release/$b-m4" "$OUT/$b-m4-$f"
    llvm-size -A "$OUT/$b-m4-$f" | awk -v e=$b-$f '/^\.text/{t=$2} /^\.rodata/{r=$2} /^\.data/{d=$2} /^\.bss/{s=$2}
      END{printf "%-22s .text+.rodata %7d  .data %5d  .bss %7d\n", e, t+r, d, s}'
  done
  E=$OUT/$b-m4-full
  A=$(llvm-nm "$E" | awk '/ T mark_server_enter$/{print "enter=0x"$1} / T mark_server_leave$/{print "leave=0x"$1} / T mark_phase$/{print "phase=0x"$1}' | paste -sd, -)
  echo "== $b: handshakes (phase 1: the server's configuration, 2: TLS 1.3, 3: TLS 1.2, then arenas too small)"
  timeout 600 qemu-system-arm -M mps2-an386 -nographic -semihosting-config enable=on,target=native \
    -icount shift=0 -kernel "$E" -plugin "$OUT/marks.so,$A" -d plugin || true
done
# rustls with the spike's own minimal provider (rustls-spike/src/own.rs).
for f in own-provider own-provider,server-only; do
  RUSTFLAGS="-C link-arg=-Tlink.x" cargo build -q --release --bin rustls-m4 --target $T --features $f
  n=rustls-m4-$(echo $f | tr , -)
  cp "$CARGO_TARGET_DIR/$T/release/rustls-m4" "$OUT/$n"
  llvm-size -A "$OUT/$n" | awk -v e=$n '/^\.text/{t=$2} /^\.rodata/{r=$2} /^\.data/{d=$2} /^\.bss/{s=$2}
    END{printf "%-22s .text+.rodata %7d  .data %5d  .bss %7d\n", e, t+r, d, s}'
done
E=$OUT/rustls-m4-own-provider
A=$(llvm-nm "$E" | awk '/ T mark_server_enter$/{print "enter=0x"$1} / T mark_server_leave$/{print "leave=0x"$1} / T mark_phase$/{print "phase=0x"$1}' | paste -sd, -)
echo "== rustls with its own provider: handshakes"
timeout 600 qemu-system-arm -M mps2-an386 -nographic -semihosting-config enable=on,target=native \
  -icount shift=0 -kernel "$E" -plugin "$OUT/marks.so,$A" -d plugin || true
