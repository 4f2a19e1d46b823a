#!/bin/sh
# Test PKI for the TLS engine spike (spikes/tls): run `sh make.sh` here.
# ca: the plant's CA (P-256); server: the device's self-signed P-256 cert;
# operator / viewer / norole: client certs from the CA (the Modbus/TCP
# Security role extension 1.3.6.1.4.1.50316.802.1, a UTF8String);
# big: a CA-signed client cert padded to about 40 KiB; other: from another CA.
set -eu
ROLE=1.3.6.1.4.1.50316.802.1
ec() { openssl ecparam -name prime256v1 -genkey -noout | openssl pkcs8 -topk8 -nocrypt -out "$1.key"; }
ec ca
openssl req -x509 -new -key ca.key -subj /CN=spike-plant-ca -days 3650 -out ca.pem \
  -addext basicConstraints=critical,CA:TRUE -addext keyUsage=critical,keyCertSign
ec other-ca
openssl req -x509 -new -key other-ca.key -subj /CN=other-ca -days 3650 -out other-ca.pem \
  -addext basicConstraints=critical,CA:TRUE -addext keyUsage=critical,keyCertSign
ec server
openssl req -x509 -new -key server.key -subj /CN=adapter.local -days 3650 -out server.pem \
  -addext subjectAltName=DNS:adapter.local,IP:127.0.0.1 -addext basicConstraints=critical,CA:FALSE
client() { # name ca extra-ext...
  name=$1; ca=$2; shift 2
  ec "$name"
  openssl req -new -key "$name.key" -subj "/CN=$name" -out "$name.csr"
  printf 'basicConstraints=critical,CA:FALSE\nkeyUsage=critical,digitalSignature\nextendedKeyUsage=clientAuth\n' > "$name.ext"
  for e in "$@"; do printf '%s\n' "$e" >> "$name.ext"; done
  openssl x509 -req -in "$name.csr" -CA "$ca.pem" -CAkey "$ca.key" -CAcreateserial -days 3650 \
    -extfile "$name.ext" -out "$name.pem"
  rm -f "$name.csr" "$name.ext"
}
client operator ca "$ROLE=ASN1:UTF8String:operator"
client viewer ca "$ROLE=ASN1:UTF8String:viewer"
client norole ca
client stranger other-ca "$ROLE=ASN1:UTF8String:operator"
PAD=$(head -c 20480 /dev/zero | od -An -tx1 -v | tr -d ' \n')
client big ca "$ROLE=ASN1:UTF8String:operator" "1.3.6.1.4.1.50316.802.99=DER:$PAD$PAD"
# mid: padded to about 15 KiB, the largest that fits a 16 KiB record buffer
PAD=$(head -c 7500 /dev/zero | od -An -tx1 -v | tr -d ' \n')
client mid ca "$ROLE=ASN1:UTF8String:operator" "1.3.6.1.4.1.50316.802.99=DER:$PAD$PAD"
for f in *.pem; do openssl x509 -in "$f" -outform der -out "${f%.pem}.der"; done
for f in *.key; do openssl pkcs8 -topk8 -nocrypt -in "$f" -outform der -out "${f%.key}.key.der"; done
rm -f *.srl
