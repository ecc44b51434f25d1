#!/usr/bin/env bash
# The farm figures of the README: a synthetic shooting day of 4 takes of 1,800 frames each
# (2 minutes of 60 fps footage in all, helmet slip on) replayed take after take by one
# process, then as the OpenJD job `helmcap farm job` writes, run on this machine by
# `openjd run` as one farm worker would (chunks of 600 frames, 60 warm-up); then the time
# of one take's merge and the size of the report. Each timing is the median of RUNS runs.
# The single pass runs with the job's label restarts (--relabel-every 600 --relabel-lead 60),
# which make it the merged takes' reference byte for byte; one plain replay per take (no
# restarts) gives the labeled share the restarts cost.
#
#   scripts/bench-farm.sh [DIR]     (HELMCAP=path/to/release/helmcap, RUNS=3)
set -euo pipefail
helmcap="${HELMCAP:-target/release/helmcap}"
dir="${1:-/tmp/helmcap-bench-farm}"
runs="${RUNS:-3}"
openjd="${OPENJD:-$HOME/.cache/helmcap-python/bin/openjd}"
mkdir -p "$dir/day"
for i in 1 2 3 4; do
  if [ ! -f "$dir/day/take_0$i/frames.csv" ]; then
    "$helmcap" synth --out "$dir/day/take_0$i" -n 1800 --seed "$i" --slip-mm 1 > /dev/null
  fi
done
median() { sort -n | awk '{a[NR]=$1} END {print a[int((NR+1)/2)]}'; }
now() { date +%s.%N; }
calc() { awk "BEGIN { printf \"%.2f\", $1 }"; }
# The dataset and LGI index caches are built once, before any timing.
"$helmcap" replay "$dir/day/take_01" --frames 0..2 --out "$dir/warm" --overwrite --quiet > /dev/null

single=()
for _ in $(seq "$runs"); do
  t=$(now)
  for i in 1 2 3 4; do
    "$helmcap" replay "$dir/day/take_0$i" --out "$dir/single/take_0$i" --overwrite --quiet \
      --export usd --relabel-every 600 --relabel-lead 60 > /dev/null
  done
  single+=("$(calc "$(now) - $t")")
done

"$helmcap" farm job --takes "$dir/day" --out "$dir/bundle" --results "$dir/results" \
  --chunk 600 --overlap 60 --export usd > /dev/null
params=()
while IFS= read -r line; do
  case "$line" in
    "- name: "*) name="${line#- name: }" ;;
    "  value: "*) value="${line#  value: }"; value="${value#\'}"; value="${value%\'}"
                  params+=(-p "$name=$value") ;;
  esac
done < "$dir/bundle/parameter_values.yaml"
chunked=()
for _ in $(seq "$runs"); do
  rm -rf "$dir/results"
  t=$(now)
  "$openjd" run "$dir/bundle/template.yaml" "${params[@]}" > "$dir/openjd.log" 2>&1
  chunked+=("$(calc "$(now) - $t")")
  grep -q "Session ended successfully" "$dir/openjd.log"
done
for i in 1 2 3 4; do
  for f in bundles.csv head_pose.csv tracks.csv mesh.usda; do
    cmp -s "$dir/single/take_0$i/$f" "$dir/results/take_0$i/$f" ||
      { echo "take_0$i/$f: the farm's differs from the single pass" >&2; exit 1; }
  done
done
merge=()
for _ in $(seq "$runs"); do
  t=$(now)
  "$helmcap" farm merge "$dir/results/chunks/take_01" --out "$dir/merged" --overwrite > /dev/null
  merge+=("$(calc "$(now) - $t")")
done
labeled() { sed -n 's/.*"labeled_fraction": *\([0-9.]*\).*/\1/p' "$1/metrics.json" | head -1; }
for i in 1 2 3 4; do
  "$helmcap" replay "$dir/day/take_0$i" --out "$dir/plain/take_0$i" --overwrite --quiet \
    > /dev/null
  echo "take_0$i labeled: $(labeled "$dir/plain/take_0$i") plain replay," \
    "$(labeled "$dir/results/take_0$i") farm (= single pass with restarts)"
done
s=$(printf '%s\n' "${single[@]}" | median)
c=$(printf '%s\n' "${chunked[@]}" | median)
m=$(printf '%s\n' "${merge[@]}" | median)
chunks=$(find "$dir/results/chunks" -mindepth 2 -maxdepth 2 -type d | wc -l)
echo "single process, 4 takes:      ${s} s (runs: ${single[*]})"
echo "openjd run, $chunks chunks:     ${c} s (runs: ${chunked[*]}); ratio $(calc "$c / $s")"
echo "per chunk beyond the single pass: $(calc "($c - $s) / $chunks") s"
echo "merge of one take (3 chunks, 1800 frames, USD): ${m} s (runs: ${merge[*]})"
echo "report: $(du -sb "$dir/results/report" | cut -f1) bytes in $(ls "$dir/results/report" | wc -l) files"
echo "outputs equal the single pass: yes"
