#!/usr/bin/env bash
# The application's header, <ecat/ecat.hpp>, carries the application's face only: no simulator,
# no bus machinery, no coroutine runtime, no mailbox or DC internals, and far fewer headers than
# the whole library (it pulled in 56 of the project's headers before the layers were cut).
# Usage: public_face.sh CXX INCLUDE_DIR GENERATED_INCLUDE_DIR MAX_HEADERS
set -euo pipefail
cxx=$1 include=$2 generated=$3 max=$4
headers=$(echo '#include <ecat/ecat.hpp>' |
  "$cxx" -std=c++20 -x c++ -fsyntax-only -H -I"$include" -I"$generated" - 2>&1 >/dev/null |
  grep -o 'ecat/[a-z0-9_/]*\.hpp' | sort -u)
count=$(printf '%s\n' "$headers" | wc -l)
echo "ecat.hpp pulls in $count of the project's headers (at most $max):"
printf '  %s\n' $headers
status=0
for forbidden in 'ecat/sim/' 'ecat/bus/bus.hpp' 'ecat/bus/realtime.hpp' 'ecat/exec/' \
  'ecat/master/mailbox.hpp' 'ecat/master/coe_client.hpp' 'ecat/master/dc.hpp' \
  'ecat/capture/' 'ecat/config/'; do
  if printf '%s\n' "$headers" | grep -q "^$forbidden"; then
    echo "FAIL: ecat.hpp pulls in $forbidden" >&2
    status=1
  fi
done
if [ "$count" -gt "$max" ]; then
  echo "FAIL: $count headers, more than $max" >&2
  status=1
fi
exit $status
