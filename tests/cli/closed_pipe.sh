#!/usr/bin/env bash
# Usage: closed_pipe.sh BFLOW ARGS...
# Runs `BFLOW ARGS... | head -c 100`: the reader goes away after 100 bytes while bflow still has
# more to write than the pipe holds. bflow must then end with exit code 1 and exactly the one
# stderr line "error: stdout: write failed (Broken pipe)", not die of SIGPIPE (status 141) as a
# classic filter does, and not report success.
set -u -o pipefail
stderr_file=$(mktemp) || exit 2
trap 'rm -f "$stderr_file"' EXIT
"$@" 2>"$stderr_file" | head -c 100 >/dev/null
statuses=("${PIPESTATUS[@]}")
stderr=$(cat "$stderr_file")
echo "$* | head -c 100: exit statuses ${statuses[*]}; stderr: [$stderr]"
expected="error: stdout: write failed (Broken pipe)"
if [[ ${statuses[0]} -ne 1 ]]; then
  echo "FAIL: bflow exited with ${statuses[0]}, expected 1"
  exit 1
fi
if [[ "$stderr" != "$expected" || $(wc -l <"$stderr_file") -ne 1 ]]; then
  echo "FAIL: stderr is not exactly the line [$expected]"
  exit 1
fi
