#!/usr/bin/env bash
# The code checks CI runs before the test suite (settings in pyproject.toml): the formatter, the
# linter and the type checker over terra/, tests/, benchmarks/ and scripts/. Any finding fails.
set -uo pipefail
cd "$(dirname "$0")/.."
paths=(terra tests benchmarks scripts)
status=0
ruff format --check "${paths[@]}" || status=1
ruff check "${paths[@]}" || status=1
pyright "${paths[@]}" || status=1
if [ "$status" -ne 0 ]; then echo "lint: findings above (ruff format / ruff check --fix fix most; see pyproject.toml)"; fi
exit "$status"
