# Sourced by scripts/test and scripts/demo (not run on its own): the g++ build both use, so that
# running one after the other reuses every object instead of rebuilding the tree with other flags.
# Defines `common` (generator, -Werror, lld, ccache) and `configure_gcc` (build/gcc, -O1 -g1).

# Both builds link with lld (installed by scripts/setup): several times faster than GNU ld on the
# large test executables. They compile through ccache (also from scripts/setup): a second run, or
# one after a small change, recompiles only what changed, in this clone or a fresh one beside it
# (paths under the clone's parent folder are hashed relative to it). ECAT_CCACHE=0 compiles
# without; CCACHE_* settings of the caller win.
common=(-G Ninja -DECAT_WERROR=ON -DCMAKE_EXE_LINKER_FLAGS=-fuse-ld=lld
  -DCMAKE_SHARED_LINKER_FLAGS=-fuse-ld=lld -DCMAKE_MODULE_LINKER_FLAGS=-fuse-ld=lld)
if [ "${ECAT_CCACHE:-1}" != 0 ] && command -v ccache >/dev/null 2>&1; then
  export CCACHE_BASEDIR=${CCACHE_BASEDIR:-$(cd .. && pwd)}
  export CCACHE_NOHASHDIR=${CCACHE_NOHASHDIR:-1}
  # The tests' precompiled header: ccache reuses objects compiled with one only with these.
  export CCACHE_SLOPPINESS=${CCACHE_SLOPPINESS:-pch_defines,time_macros,include_file_mtime,include_file_ctime}
  common+=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
else
  common+=(-UCMAKE_CXX_COMPILER_LAUNCHER)
fi

# -O1 -g1: optimised enough for the realtime tests and the demo, line tables for readable stack
# traces, and much faster to compile than -O2 with full debug info (scripts/bench builds -O2 for
# figures).
configure_gcc() {
  cmake -S . -B build/gcc "${common[@]}" -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DCMAKE_CXX_COMPILER=g++ -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O1 -g1" >/dev/null
}
