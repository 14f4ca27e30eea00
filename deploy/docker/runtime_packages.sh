#!/usr/bin/env bash
# Prints the Debian packages that own the shared libraries the given binaries load (ldd), one a
# line: the runtime stage of deploy/docker/Dockerfile installs these and nothing else.
set -euo pipefail
for lib in $(ldd "$@" | awk '$2 == "=>" && $3 ~ /^\// { print $3 }' | sort -u); do
  real="$(realpath "$lib")"
  # Debian 12 merges /lib into /usr/lib: dpkg knows a file by one of the two names.
  for path in "$lib" "$real" "/usr${real#/usr}" "${real#/usr}"; do
    if owner="$(dpkg -S "$path" 2>/dev/null)"; then
      echo "${owner%%:*}"
      break
    fi
  done
done | sed 's/:amd64$//' | sort -u
