#!/usr/bin/env bash
# run.sh NAME FUZZER SECONDS WORKDIR [SHARED_DATA_DIR]
# Builds the seed corpus for one fuzz target (committed seeds + seeds extracted from the shared
# real-device data when it is there) and fuzzes for SECONDS. Exits non-zero on any crash.
set -euo pipefail
name=$1
fuzzer=$2
seconds=$3
work=$4/$name
shared=${5:-}
here=$(cd "$(dirname "$0")" && pwd)
python=${PYTHON:-python3}

mkdir -p "$work/corpus" "$work/seeds" "$work/artifacts"
if [ -d "$here/seeds/$name" ]; then
  cp -f "$here/seeds/$name"/* "$work/seeds/" 2>/dev/null || true
fi
if [ -n "$shared" ] && [ -d "$shared" ]; then
  "$python" "$here/extract_seeds.py" "$name" "$shared" "$work/seeds"
else
  echo "shared data not found: fuzzing from committed seeds only"
fi
echo "fuzz.$name: $(ls "$work/seeds" | wc -l) seeds, $seconds s"
exec "$fuzzer" -max_total_time="$seconds" -rss_limit_mb=2048 -timeout=10 -print_final_stats=1 \
  -artifact_prefix="$work/artifacts/" "$work/corpus" "$work/seeds"
