#!/bin/sh
# run_fuzz.sh SEEDS_BIN KIND FUZZER WORKDIR SECONDS: a bounded libFuzzer run over fresh seeds.
# The corpus it grows lives in WORKDIR (a build folder) and is started afresh every run.
set -eu
seeds_bin=$1 kind=$2 fuzzer=$3 work=$4 seconds=$5
rm -rf "$work"
mkdir -p "$work/seeds" "$work/corpus" "$work/artifacts"
"$seeds_bin" "$kind" "$work/seeds"
exec "$fuzzer" -max_total_time="$seconds" -runs=50000000 -timeout=10 -rss_limit_mb=2048 \
  -max_len=65536 -print_final_stats=1 -artifact_prefix="$work/artifacts/" \
  "$work/corpus" "$work/seeds"
