#!/usr/bin/env bash
# Regenerates the seed corpus of sweep_resume_fuzz (tests/fuzz/corpus/sweep_resume/) from a
# built `bflow`: files to give to `bflow sweep ... --output F --resume`, each seed the selector
# byte of the harness ('j': JSON lines, 'c': CSV) followed by the content of F. Run it again
# whenever the output format of `bflow sweep` changes, and commit the result.
#
#   tests/fuzz/make_resume_seeds.sh [BFLOW]    # default: build/cli/bflow
#
# The seeds, for each format: the whole output of the harness's sweep; prefixes of it cut at
# various bytes (inside the first line, at and around the line ends, in the middle of a record,
# one byte short of the end); the whole output with its last record repeated; the output of
# other sweeps (other varied values, another direction, another scene, the other format); a
# text without a newline, CRLF line ends and binary junk; an empty F; and the empty input (no F).
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
bflow=${1:-$root/build/cli/bflow}
if [[ ! -x $bflow ]]; then
  echo "make_resume_seeds.sh: $bflow is not an executable (build the target bflow_command)" >&2
  exit 2
fi
corpus=$root/tests/fuzz/corpus/sweep_resume
work=$(mktemp -d "${TMPDIR:-/tmp}/bflow-resume-seeds.XXXXXX")
trap 'rm -rf "$work"' EXIT

# The harness's sweep (sweep_resume_fuzz.cc), its format and its output file last.
sweep() {  # sweep FORMAT OUTPUT [options replacing the grid and the direction...]
  local format=$1 output=$2
  shift 2
  local grid=(--vary 0=-1:-0.1:4 --dx 1,0)
  if (($# > 0)); then grid=("$@"); fi
  "$bflow" sweep --scene pwconst "${grid[@]}" --quiet --threads 1 --format "$format" \
    --output "$output" 2>/dev/null
}

seed() {  # seed NAME SELECTOR FILE: the selector byte, then the file
  { printf '%s' "$2"; cat "$3"; } >"$work/seeds/$1"
}

mkdir -p "$work/seeds"
for format in jsonl csv; do
  s=${format:0:1}  # j or c
  whole=$work/whole.$format
  sweep "$format" "$whole"
  seed "whole_$format" "$s" "$whole"

  # Prefixes: cut inside the first line, around the line ends, in a record, near the end.
  size=$(wc -c <"$whole")
  mapfile -t ends < <(awk '{ total += length($0) + 1; print total }' "$whole")
  cuts=(1 5 $((ends[0] / 2)) $((ends[0] - 1)) "${ends[0]}" $((ends[0] + 1))
        $(((ends[0] + ends[1]) / 2)) "${ends[1]}" $((ends[1] + 3)) $((size / 2))
        $((size - 1)))
  for cut in "${cuts[@]}"; do
    head -c "$cut" "$whole" >"$work/cut"
    seed "cut_${format}_$cut" "$s" "$work/cut"
  done

  # The whole output and its last record again: a record beyond the grid.
  { cat "$whole"; tail -n 1 "$whole"; } >"$work/extra"
  seed "extra_record_$format" "$s" "$work/extra"

  # Other sweeps: other values of the same axis, another direction, another scene; a prefix of
  # one of them; the other format.
  sweep "$format" "$work/values" --vary 0=-1:-0.2:4 --dx 1,0
  seed "other_values_$format" "$s" "$work/values"
  sweep "$format" "$work/direction" --vary 0=-1:-0.1:4 --dx 0,1
  seed "other_direction_$format" "$s" "$work/direction"
  head -c $((ends[1] + 10)) "$work/direction" >"$work/cut"
  seed "other_direction_cut_$format" "$s" "$work/cut"
  "$bflow" sweep --scene biped --vary 2=-0.01:0.01:4 --dx 0,0,1,0,0,0 --quiet --threads 1 \
    --format "$format" --output "$work/biped" 2>/dev/null
  seed "other_scene_$format" "$s" "$work/biped"
  other=csv
  [[ $format == csv ]] && other=jsonl
  sweep "$other" "$work/other"
  seed "other_format_$format" "$s" "$work/other"

  # Not outputs at all.
  printf 'index,x[0],status' >"$work/text"
  seed "text_no_newline_$format" "$s" "$work/text"
  sed 's/$/\r/' "$whole" >"$work/crlf"
  seed "crlf_$format" "$s" "$work/crlf"
  for i in $(seq 0 7 255) $(seq 255 -11 0); do printf "\\$(printf %03o "$i")"; done >"$work/junk"
  seed "junk_$format" "$s" "$work/junk"
  : >"$work/empty"
  seed "empty_file_$format" "$s" "$work/empty"
done
: >"$work/seeds/no_file"

mkdir -p "$corpus"
rm -f "$corpus"/*
cp "$work"/seeds/* "$corpus/"
echo "make_resume_seeds.sh: $(find "$corpus" -type f | wc -l) seeds in $corpus"
