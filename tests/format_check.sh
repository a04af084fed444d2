#!/usr/bin/env bash
# Fails when a tracked C++ file differs from what clang-format (style: .clang-format) makes.
set -euo pipefail
cd "$1"
files=$(git ls-files '*.h' '*.cc' 2>/dev/null || true)
if [[ -z "$files" ]]; then
  echo "format_check: not a git checkout, nothing to check"
  exit 0
fi
# shellcheck disable=SC2086
clang-format --dry-run --Werror -style=file $files
echo "format_check: $(echo "$files" | wc -l) files formatted"
