#!/usr/bin/env bash
# Installs the built package into a scratch prefix, then builds a consumer with find_package(ecat)
# and another with pkg-config, and runs both.
set -euo pipefail
build_dir=$1
work=$2
here=$(cd "$(dirname "$0")" && pwd)
cmake=${CMAKE_COMMAND:-cmake}
cxx=${CXX:-c++}

rm -rf "$work"
mkdir -p "$work"
"$cmake" --install "$build_dir" --prefix "$work/prefix" >/dev/null

"$cmake" -S "$here/consumer" -B "$work/consumer-build" -G Ninja \
  -DCMAKE_CXX_COMPILER="$cxx" -DCMAKE_PREFIX_PATH="$work/prefix" >/dev/null
"$cmake" --build "$work/consumer-build" >/dev/null
"$work/consumer-build/consumer"

libdir=$(find "$work/prefix" -name ecat.pc -printf '%h\n' | head -n 1)
# shellcheck disable=SC2046
"$cxx" -o "$work/consumer-pc" "$here/consumer/main.cpp" \
  $(PKG_CONFIG_PATH="$libdir" pkg-config --cflags --libs ecat)
"$work/consumer-pc"
echo "install check passed"
