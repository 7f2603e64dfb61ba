#!/usr/bin/env bash
# Installs the built package into a scratch prefix (the default install plus the `static`
# component), then builds tests/install/consumer four ways, each the way README "Using the
# library" documents it, and runs each against the built-in simulated ring:
#   1. find_package(ecat), ecat::ecat (libecat.so) — with fmt, pugixml and yaml-cpp hidden from
#      find_package: a program using the shared library must not need them; examples/*.cpp too;
#   2. find_package(ecat COMPONENTS static), ecat::ecat_static (libecat.a);
#   3. pkg-config --cflags --libs ecat — with only ecat.pc visible to pkg-config;
#   4. pkg-config --cflags --libs ecat-static.
# Usage: run.sh BUILD_DIR WORK_DIR. Environment: CXX (the build's compiler: the consumer links the
# sanitizer runtime a sanitizer build's library needs through the package's own flags),
# CMAKE_COMMAND.
set -euo pipefail
build_dir=$1
work=$2
here=$(cd "$(dirname "$0")" && pwd)
source_dir=$(cd "$here/../.." && pwd)
cmake=${CMAKE_COMMAND:-cmake}
cxx=${CXX:-c++}
ring=$source_dir/examples/default.yaml
started=$SECONDS

rm -rf "$work"
mkdir -p "$work"
prefix=$work/prefix
"$cmake" --install "$build_dir" --prefix "$prefix" >/dev/null
"$cmake" --install "$build_dir" --prefix "$prefix" --component static >/dev/null
pcdir=$(find "$prefix" -name ecat.pc -printf '%h\n' | head -n 1)
libdir=$(dirname "$pcdir")

# What a program linked with the shared / the static library depends on at run time.
check_linkage() {  # BINARY shared|static
  if readelf -d "$1" | grep -q 'NEEDED.*libecat\.so'; then linked=shared; else linked=static; fi
  if [[ $linked != "$2" ]]; then
    echo "$1: expected a $2 link of libecat, found $linked" >&2
    exit 1
  fi
}

build_with_cmake() {  # NAME CMAKE_ARGS...
  local name=$1
  shift
  "$cmake" -S "$here/consumer" -B "$work/$name" -G Ninja -DCMAKE_BUILD_TYPE=Debug \
    -DCMAKE_CXX_FLAGS_DEBUG=-O0 -DCMAKE_CXX_COMPILER="$cxx" -DCMAKE_PREFIX_PATH="$prefix" \
    "$@" >"$work/$name.log" || { cat "$work/$name.log" >&2; exit 1; }
  "$cmake" --build "$work/$name" -j 2 >>"$work/$name.log" || { cat "$work/$name.log" >&2; exit 1; }
}

echo "-- find_package(ecat): ecat::ecat (shared)"
examples=$(printf '%s;' "$source_dir"/examples/*.cpp)
build_with_cmake cmake-shared -DCMAKE_DISABLE_FIND_PACKAGE_fmt=ON \
  -DCMAKE_DISABLE_FIND_PACKAGE_pugixml=ON -DCMAKE_DISABLE_FIND_PACKAGE_yaml-cpp=ON \
  "-DCONSUMER_EXAMPLES=$examples"
check_linkage "$work/cmake-shared/consumer" shared
"$work/cmake-shared/consumer" "$ring"  # (the examples are built, not run: CTest runs them)

echo "-- find_package(ecat COMPONENTS static): ecat::ecat_static"
build_with_cmake cmake-static -DCONSUMER_STATIC=ON
check_linkage "$work/cmake-static/consumer" static
"$work/cmake-static/consumer" "$ring"

# pkg-config: only the installed .pc files (ecat.pc must need nothing else) ...
echo "-- pkg-config --cflags --libs ecat (shared)"
# shellcheck disable=SC2046
"$cxx" -o "$work/pc-shared" "$here/consumer/main.cpp" \
  $(PKG_CONFIG_LIBDIR="$pcdir" pkg-config --cflags --libs ecat) -Wl,-rpath,"$libdir"
check_linkage "$work/pc-shared" shared
"$work/pc-shared" "$ring"

# ... and, for libecat.a, the system's too (fmt, yaml-cpp and pugixml are public there).
echo "-- pkg-config --cflags --libs ecat-static"
# shellcheck disable=SC2046
"$cxx" -o "$work/pc-static" "$here/consumer/main.cpp" \
  $(PKG_CONFIG_PATH="$pcdir" pkg-config --cflags --libs ecat-static)
check_linkage "$work/pc-static" static
"$work/pc-static" "$ring"

echo "install check passed in $((SECONDS - started)) s"
