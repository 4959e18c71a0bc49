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

# A build that runs out of disk fails late, at a link, with "No space left on device": say so
# up front. Usage: warn_if_low_disk GB WHAT (the space WHAT needs in this checkout's file system).
warn_if_low_disk() {
  local need_gb=$1 what=$2 have_gb
  have_gb=$(df -P -k . | awk 'NR == 2 { print int($4 / 1048576) }')
  if [ -n "$have_gb" ] && [ "$have_gb" -lt "$need_gb" ]; then
    echo "warning: $what needs about ${need_gb} GB free here; this file system has ${have_gb} GB." >&2
    echo "warning: the build may stop with 'No space left on device' (free space, then run again)." >&2
  fi
}
