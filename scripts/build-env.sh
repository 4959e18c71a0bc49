# Sourced by main-job.sh and test.sh, so both configure build/ the same way and share its objects.
# ccache (installed by setup.sh) makes a repeated run rebuild only what changed. Paths are hashed
# relative to the checkout, so a fresh clone in another folder reuses the same cache.
launcher=()
if command -v ccache >/dev/null; then
  export CCACHE_BASEDIR="$PWD" CCACHE_NOHASHDIR=1
  launcher=(-DCMAKE_C_COMPILER_LAUNCHER=ccache -DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
fi
# The release build, warnings as errors: Debian 12's compiler is the one the code is kept clean
# for.
release_config=(-G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DDEEPCANVAS_WERROR=ON "${launcher[@]}")
