#!/usr/bin/env bash
# DDS Security material for configs/dds/secure.xml, made with openssl (docs/deployment.md
# "Secure profile"):
#   ca_cert.pem, ca_key.pem        the deployment's CA: identity CA and permissions CA
#   <id>_cert.pem, <id>_key.pem    identities signed by it: server, client, observer (and --client NAME)
#   governance.xml / .p7s          domain rules (authentication required, discovery, liveliness and
#                                  data encrypted, read and write access control), signed by the CA
#   permissions.xml / .p7s         per identity, signed by the CA: the server alone writes poses,
#                                  results, status, views and the map directory; clients write frames,
#                                  session control and requests; observers write session control
#                                  and requests only (they query maps, never stream)
#   rogue/                         with --rogue, for tests: an 'intruder' identity and documents
#                                  signed by a CA of its own, which the deployment does not trust
#
#   bash deploy/make_certs.sh OUT_DIR [--client NAME]... [--observer NAME]... [--days N] [--rogue]
#
# Private keys are written with mode 600 into OUT_DIR: keep them out of the repository (tests
# make theirs in a temporary folder at run time). Subject names are O=featureslam,CN=<id>.
set -euo pipefail

usage() { awk 'NR > 1 && !/^#/ { exit } NR > 1 { sub(/^# ?/, ""); print }' "${BASH_SOURCE[0]}"; }
[[ $# -ge 1 && "$1" != -* ]] || { usage >&2; exit 2; }
OUT="$1"; shift
CLIENTS=(client) OBSERVERS=(observer) DAYS=3650 ROGUE=0
while [[ $# -gt 0 ]]; do
  case "$1" in
    --client) CLIENTS+=("$2"); shift ;;
    --observer) OBSERVERS+=("$2"); shift ;;
    --days) DAYS="$2"; shift ;;
    --rogue) ROGUE=1 ;;
    -h|--help) usage; exit 0 ;;
    *) echo "make_certs.sh: unknown option '$1'" >&2; exit 2 ;;
  esac
  shift
done
command -v openssl >/dev/null || { echo "make_certs.sh: openssl is needed (apt-get install openssl)" >&2; exit 1; }
mkdir -p "$OUT"
umask 077

subject() { echo "/O=featureslam/CN=$1"; }
# The same name as the permissions document writes it: no spaces after commas.
subject_name() { echo "O=featureslam,CN=$1"; }

# make_ca DIR NAME: an EC P-256 CA, self-signed.
make_ca() {
  openssl ecparam -name prime256v1 -genkey -noout -out "$1/ca_key.pem"
  openssl req -x509 -new -key "$1/ca_key.pem" -sha256 -days "$DAYS" -subj "$(subject "$2")" \
    -out "$1/ca_cert.pem"
}

# make_identity DIR ID: a key and a certificate signed by DIR's CA.
make_identity() {
  openssl ecparam -name prime256v1 -genkey -noout -out "$1/$2_key.pem"
  openssl req -new -key "$1/$2_key.pem" -subj "$(subject "$2")" -out "$1/$2.csr"
  openssl x509 -req -in "$1/$2.csr" -CA "$1/ca_cert.pem" -CAkey "$1/ca_key.pem" -CAcreateserial \
    -sha256 -days "$DAYS" -out "$1/$2_cert.pem" 2>/dev/null
  rm -f "$1/$2.csr"
}

write_governance() {
  cat >"$1/governance.xml" <<XML
<?xml version="1.0" encoding="UTF-8"?>
<!-- featureslam governance: every participant authenticates; discovery, liveliness and data are
     encrypted; reading and writing any topic needs a grant in permissions.xml. -->
<dds xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance"
     xsi:noNamespaceSchemaLocation="http://www.omg.org/spec/DDS-SECURITY/20170901/omg_shared_ca_governance.xsd">
  <domain_access_rules>
    <domain_rule>
      <domains><id_range><min>0</min><max>230</max></id_range></domains>
      <allow_unauthenticated_participants>false</allow_unauthenticated_participants>
      <enable_join_access_control>true</enable_join_access_control>
      <discovery_protection_kind>ENCRYPT</discovery_protection_kind>
      <liveliness_protection_kind>ENCRYPT</liveliness_protection_kind>
      <rtps_protection_kind>NONE</rtps_protection_kind>
      <topic_access_rules>
        <topic_rule>
          <topic_expression>*</topic_expression>
          <enable_discovery_protection>true</enable_discovery_protection>
          <enable_liveliness_protection>true</enable_liveliness_protection>
          <enable_read_access_control>true</enable_read_access_control>
          <enable_write_access_control>true</enable_write_access_control>
          <metadata_protection_kind>ENCRYPT</metadata_protection_kind>
          <data_protection_kind>ENCRYPT</data_protection_kind>
        </topic_rule>
      </topic_access_rules>
    </domain_rule>
  </domain_access_rules>
</dds>
XML
}

# grant NAME SUBJECT PUBLISHED SUBSCRIBED: one grant; topics are the last part of <prefix>/<topic>.
grant() {
  local topics_xml
  topics_xml() { local t; set -f; for t in $1; do printf '<topic>*/%s</topic>' "$t"; done; set +f; }
  cat <<XML
    <grant name="$1">
      <subject_name>$2</subject_name>
      <validity><not_before>2020-01-01T00:00:00</not_before><not_after>2045-01-01T00:00:00</not_after></validity>
      <allow_rule>
        <domains><id_range><min>0</min><max>230</max></id_range></domains>
        <publish><topics>$(topics_xml "$3")</topics></publish>
        <subscribe><topics>$(topics_xml "$4")</topics></subscribe>
      </allow_rule>
      <default>DENY</default>
    </grant>
XML
}

# write_permissions DIR "server-ids" "client-ids" "observer-ids" ["all-topics-ids"]
write_permissions() {
  {
    cat <<XML
<?xml version="1.0" encoding="UTF-8"?>
<!-- featureslam permissions (docs/deployment.md): the server alone writes poses, results, status,
     views and the map directory; clients write frames, session control and requests; observers write
     session control and requests only. Anything not granted is denied. -->
<dds xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance"
     xsi:noNamespaceSchemaLocation="http://www.omg.org/spec/DDS-SECURITY/20170901/omg_shared_ca_permissions.xsd">
  <permissions>
XML
    for id in $2; do grant "server_$id" "$(subject_name "$id")" "poses results status views maps" "frames session requests maps"; done
    for id in $3; do grant "client_$id" "$(subject_name "$id")" "frames session requests" "poses results status views maps"; done
    for id in $4; do grant "observer_$id" "$(subject_name "$id")" "session requests" "poses results status views maps"; done
    for id in ${5:-}; do grant "all_$id" "$(subject_name "$id")" "*" "*"; done
    cat <<XML
  </permissions>
</dds>
XML
  } >"$1/permissions.xml"
}

# sign DIR NAME: NAME.xml -> NAME.p7s, S/MIME signed by DIR's CA (what the plugins verify).
sign() {
  openssl smime -sign -in "$1/$2.xml" -text -out "$1/$2.p7s" -signer "$1/ca_cert.pem" \
    -inkey "$1/ca_key.pem"
}

make_ca "$OUT" "featureslam-ca"
for id in server "${CLIENTS[@]}" "${OBSERVERS[@]}"; do make_identity "$OUT" "$id"; done
write_governance "$OUT"
write_permissions "$OUT" "server" "${CLIENTS[*]}" "${OBSERVERS[*]}"
sign "$OUT" governance
sign "$OUT" permissions

if [[ $ROGUE -eq 1 ]]; then
  mkdir -p "$OUT/rogue"
  make_ca "$OUT/rogue" "rogue-ca"
  make_identity "$OUT/rogue" intruder
  write_governance "$OUT/rogue"
  # The intruder grants itself everything, under a CA the deployment does not trust.
  write_permissions "$OUT/rogue" "" "" "" "intruder"
  sign "$OUT/rogue" governance
  sign "$OUT/rogue" permissions
fi
rm -f "$OUT"/ca_cert.srl "$OUT"/rogue/ca_cert.srl
chmod 644 "$OUT"/*.pem "$OUT"/*.xml "$OUT"/*.p7s
chmod 600 "$OUT"/*_key.pem
echo "DDS Security material in $OUT: CA, identities: server ${CLIENTS[*]} ${OBSERVERS[*]}$([[ $ROGUE -eq 1 ]] && echo ', rogue/intruder')"
